// Helpers shared by the sampler kernels (owners in engine/src/sampler/): the occupancy
// grid's geometry and cell lookup, a ray/box slab test, and (through common/hash.wgsl)
// the PCG hash RNG. Include only; mirrors `OccupancyGeom` in engine/src/sampler/occupancy.rs.

//#include "common/hash.wgsl"

// The occupancy grid: `res`^3 cells over [aabb_min, aabb_max], cell index
// x + res * (y + res * z); occupancy bit of cell c is bit (c & 31) of word c >> 5.
struct OccupancyGeom {
    aabb_min: vec3<f32>,
    res: u32,
    aabb_max: vec3<f32>,
    n_cells: u32,
}

// Integer cell coordinates of point p (may lie outside [0, res)).
fn grid_cell_coord(g: OccupancyGeom, p: vec3<f32>) -> vec3<i32> {
    let u = (p - g.aabb_min) / (g.aabb_max - g.aabb_min) * f32(g.res);
    return vec3<i32>(floor(u));
}

fn grid_cell_inside(g: OccupancyGeom, c: vec3<i32>) -> bool {
    let r = i32(g.res);
    return all(c >= vec3<i32>(0)) && all(c < vec3<i32>(r));
}

fn grid_cell_index(g: OccupancyGeom, c: vec3<i32>) -> u32 {
    return u32(c.x) + g.res * (u32(c.y) + g.res * u32(c.z));
}

// Corner of cell coordinate c (c may equal res for the far corner).
fn grid_cell_corner(g: OccupancyGeom, c: vec3<i32>) -> vec3<f32> {
    return g.aabb_min + (g.aabb_max - g.aabb_min) * (vec3<f32>(c) / f32(g.res));
}

// Reciprocal direction; components with |d| below 1e-30 map to +-1e30 (sign of d,
// +0 counts as positive) so that slab tests never produce 0 * inf.
fn safe_inverse_dir(d: vec3<f32>) -> vec3<f32> {
    let big = select(vec3<f32>(-1e30), vec3<f32>(1e30), d >= vec3<f32>(0.0));
    return select(1.0 / d, big, abs(d) < vec3<f32>(1e-30));
}

// Slab test: (t_near, t_far) of the ray o + t d against the box; empty if near > far.
fn ray_box(o: vec3<f32>, inv_d: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>) -> vec2<f32> {
    let t1 = (bmin - o) * inv_d;
    let t2 = (bmax - o) * inv_d;
    let tn = min(t1, t2);
    let tf = max(t1, t2);
    return vec2<f32>(max(max(tn.x, tn.y), tn.z), min(min(tf.x, tf.y), tf.z));
}
