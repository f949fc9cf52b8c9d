//! Geometry out of a trained model: the surface of its density field as a triangle
//! mesh, and point clouds from its rendered depth.
//!
//! * [`extract_mesh`]: densities on a regular grid over the scene's box (or a given
//!   box) through the field's own density query on the GPU ([`Model::densities`]),
//!   marching tetrahedra on the CPU ([`crate::mesh::marching_tetrahedra`]) at a density
//!   level ([`default_level`] unless given), then vertex colours from the field's
//!   forward pass seen head-on: at each vertex along its inward normal (the direction a
//!   camera facing the surface looks), [`Model::colors_at`].
//! * [`depth_points`]: every pixel of the chosen views whose rendered opacity reaches a
//!   minimum, placed at its terminated depth (`depth / opacity`, as depth maps show) on
//!   its ray, with the rendered colour (the background taken back out where it is a
//!   constant colour) and the rendered normal.
//!
//! Forward-facing (NDC) scenes: the field lives in NDC, so the grid spans the NDC box;
//! output is mapped back to world space ([`crate::data::NdcParams::ndc_to_world`]),
//! except the mesh with `keep_ndc`. Triangles and points beyond NDC `z = 0.99` (100
//! near-plane distances and further, up to infinity) are dropped from world output.
//!
//! Invariants: output is deterministic for a model; triangles face outward (toward
//! lower density) in either space (the NDC map reverses orientation, so the winding is
//! flipped with it); normals are unit or zero; colours are the field's, in `0..=255`.

use glam::Vec3;

use super::{Model, TrainError};
use crate::data::Scene;
use crate::gpu::Gpu;
use crate::mesh::{ScalarGrid, TriMesh, marching_tetrahedra};
use crate::render::Background;

/// NDC depth beyond which geometry is not mapped to world space (about 100 near-plane
/// distances; NDC `z = 1` is infinity).
const NDC_FAR_Z: f32 = 0.99;

/// How to extract a mesh ([`extract_mesh`]).
#[derive(Clone, Copy, Debug)]
pub struct MeshOptions {
    /// Grid cells along the longest side of the box (the other sides get cells of the
    /// same size, at least one).
    pub resolution: u32,
    /// Density level of the surface (`None`: [`default_level`]).
    pub level: Option<f32>,
    /// The box to mesh, in the field's space (`None`: the scene's box).
    pub bbox: Option<[Vec3; 2]>,
    /// Forward-facing scenes: keep NDC coordinates instead of mapping to world space.
    pub keep_ndc: bool,
}

/// The default surface level: the density at which one marching step of the run is
/// half opaque, `ln 2 / step` (`step`: the sampler's, `sampler.steps_per_diagonal` of
/// the box diagonal). A ray that crosses density above it stops half its light within
/// one sample: about where its rendered depth lies. It scales with the step the field
/// was fitted with, so it means the same in every scene.
pub fn default_level(model: &Model, scene: &Scene) -> f32 {
    std::f32::consts::LN_2 / model.config.sampler.step_for(scene.aabb)
}

/// The density grid of `model` over `lo..hi` with `resolution` cells along its
/// longest side; `progress(done, total)` in points.
pub fn density_grid(
    gpu: &Gpu,
    model: &Model,
    lo: Vec3,
    hi: Vec3,
    resolution: u32,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ScalarGrid, TrainError> {
    let size = hi - lo;
    let cell = size.max_element() / resolution.max(1) as f32;
    let dims = size.to_array().map(|s| ((s / cell).round() as usize).max(1) + 1);
    let mut grid = ScalarGrid { dims, lo, hi, values: Vec::new() };
    let points: Vec<Vec3> = grid.points().collect();
    grid.values = model.densities(gpu, &points, progress)?;
    Ok(grid)
}

/// A mesh of [`extract_mesh`] and the grid it came from.
pub struct ExtractedMesh {
    pub mesh: TriMesh,
    /// The density level used.
    pub level: f32,
    /// Grid points per axis.
    pub dims: [usize; 3],
    /// The smallest and largest density on the grid (NaN ignored).
    pub density_range: [f32; 2],
}

/// The surface of `model`'s density field (see the module doc).
pub fn extract_mesh(
    gpu: &Gpu,
    model: &mut Model,
    scene: &Scene,
    opts: &MeshOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ExtractedMesh, TrainError> {
    let [lo, hi] = opts.bbox.unwrap_or(scene.aabb);
    let grid = density_grid(gpu, model, lo, hi, opts.resolution, progress)?;
    let density_range = grid.values.iter().fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], &v| [a.min(v), b.max(v)]);
    let level = opts.level.unwrap_or_else(|| default_level(model, scene));
    let mut mesh = marching_tetrahedra(&grid, level);
    let dirs: Vec<Vec3> = mesh.normals.iter().map(|n| if *n == Vec3::ZERO { Vec3::NEG_Z } else { -*n }).collect();
    mesh.colors = model.colors_at(gpu, &mesh.positions, &dirs)?.into_iter().map(to_u8).collect();
    if let (Some(ndc), false) = (scene.ndc, opts.keep_ndc) {
        mesh.retain_triangles(|m, t| m.corners(t).iter().all(|p| p.z < NDC_FAR_Z));
        for p in &mut mesh.positions {
            *p = ndc.ndc_to_world(*p);
        }
        for t in &mut mesh.triangles {
            t.swap(1, 2);
        }
        mesh.normals = mesh.vertex_normals_from_faces();
    }
    Ok(ExtractedMesh { mesh, level, dims: grid.dims, density_range })
}

fn to_u8(c: [f32; 3]) -> [u8; 3] {
    c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// The points of [`depth_points`] (see the module doc): views `views` of `scene`,
/// pixels with rendered opacity at least `min_opacity`; `progress(done, total)` in views.
pub fn depth_points(
    gpu: &Gpu,
    model: &mut Model,
    scene: &Scene,
    views: &[usize],
    min_opacity: f32,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TriMesh, TrainError> {
    let background = match model.render_config().background {
        Background::Color { rgb } => Some(Vec3::from(rgb)),
        Background::Black | Background::Auto => Some(Vec3::ZERO),
        // Per ray: taken from the model's learned background below.
        Background::Random | Background::Learned => None,
    };
    let mut cloud = TriMesh::default();
    for (k, &v) in views.iter().enumerate() {
        let r = model.render_view(gpu, scene, v)?;
        let rays = scene.image_rays(v);
        let learned = model.background.as_ref().map(|bg| {
            let gpu_rays: Vec<_> = rays.iter().map(|r| super::rays::to_gpu_ray(scene, r)).collect();
            let dirs = bg.ray_dirs(&gpu_rays);
            bg.colors(&dirs)
        });
        let normals = r.unit_normals();
        for (i, ray) in rays.iter().enumerate() {
            let a = r.opacity[i];
            if !(a >= min_opacity && a > 0.0) {
                continue;
            }
            let p = ray.at(r.depth[i] / a);
            let (p, n) = match &scene.ndc {
                None => (p, Vec3::from(normals[i])),
                Some(ndc) => {
                    if p.z >= NDC_FAR_Z {
                        continue;
                    }
                    // A normal maps with the inverse transpose of the map's Jacobian:
                    // n_world ~ J^T n_ndc, J = d ndc / d world at the point.
                    let w = ndc.ndc_to_world(p);
                    let h = 1e-3 * w.length().max(1e-3);
                    let j = glam::Mat3::from_cols_array_2d(&[0, 1, 2].map(|k| {
                        let e = Vec3::AXES[k] * h;
                        ((ndc.point_to_ndc(w + e) - ndc.point_to_ndc(w - e)) / (2.0 * h)).to_array()
                    }));
                    (w, (j.transpose() * Vec3::from(normals[i])).normalize_or_zero())
                }
            };
            let rgb = Vec3::from(r.rgb[i]);
            let bg = background.or_else(|| learned.as_ref().map(|l| Vec3::from(l[i])));
            let c = bg.map_or(rgb, |bg| (rgb - (1.0 - a) * bg) / a);
            cloud.positions.push(p);
            cloud.normals.push(n);
            cloud.colors.push(to_u8(c.to_array()));
        }
        progress(k + 1, views.len());
    }
    Ok(cloud)
}
