//! Rendering rays in segments (`sampler.render_segment`): the host's side of it. A
//! render marches each ray's first samples only, the field shades them and the
//! renderer composites them; the rays still transparent are marched again from where
//! they stopped, in segments twice as long each time, until each ray has left the
//! box, hit its cap, or its transmittance fell under the renderer's threshold (where
//! a segment turns fewer than one ray in [`FEW_OPAQUE`] opaque, the rest of every
//! ray goes in one last segment: a scene of fog or of open backgrounds would pay
//! each segment's round trip for nothing). The
//! samples behind an opaque surface, which one pass over every marched sample shades
//! for nothing, are never marched. ([`crate::train::Model::render_rays`] drives the
//! GPU; this module keeps the rays' state and composites the segments.)
//!
//! Compositing is associative: with `T_k` the transmittance before segment `k` and
//! each segment composited alone over the background `b` (the renderer's kernel,
//! `c_k = c'_k + (1 - a_k) b`), the ray's colour is `sum_k T_k c'_k + (1 - sum_k T_k a_k)
//! b`, its opacity `sum_k T_k a_k`, its depth and normal `sum_k T_k d_k` and
//! `sum_k T_k n_k`, `T_{k+1} = T_k (1 - a_k)`: one pass's outputs.
//!
//! Invariants: a ray is finished (its `t_min` set to its `t_max`, so the march gives
//! it no sample) once a segment gave it fewer samples than the segment's cap (it left
//! its range), or its transmittance fell under the threshold, or its next start would
//! not lie past its last; an unfinished ray's next segment starts at the far end of
//! its last sample, on the same grid of steps (the march anchors its grid at `t_min`).
//! The result differs from one pass only by samples past the threshold inside a
//! segment (together at most the threshold's weight) and by the rounding of the
//! restarts.

use crate::layout::{GpuRay, GpuSample, RayOutput, SampleRange};

/// A segment that turns fewer than one in this many of its rays opaque is followed by
/// one last segment for the rest of every ray.
pub const FEW_OPAQUE: usize = 10;

/// The rays of one render chunk between segments, and what their segments composited.
pub struct SegmentedRays {
    rays: Vec<GpuRay>,
    background: Vec<[f32; 3]>,
    acc: Vec<RayOutput>,
    transmittance: Vec<f32>,
    threshold: f32,
    /// Samples marched for every unfinished ray so far (they all took every cap).
    used: u32,
}

impl SegmentedRays {
    /// `rays` before their first segment; `background[i]` is what the renderer
    /// composites behind ray `i`, `threshold` the renderer's transmittance threshold.
    pub fn new(rays: &[GpuRay], background: Vec<[f32; 3]>, threshold: f32) -> Self {
        assert_eq!(rays.len(), background.len(), "one background colour per ray");
        Self {
            rays: rays.to_vec(),
            background,
            acc: vec![RayOutput::default(); rays.len()],
            transmittance: vec![1.0; rays.len()],
            threshold,
            used: 0,
        }
    }

    /// The rays to march next (finished ones have empty ranges).
    pub fn rays(&self) -> &[GpuRay] {
        &self.rays
    }

    /// Samples each unfinished ray has had so far.
    pub fn used(&self) -> u32 {
        self.used
    }

    /// Whether any ray still needs a segment.
    pub fn any_active(&self) -> bool {
        self.rays.iter().any(is_active)
    }

    /// Adds a segment marched with at most `cap` samples a ray: the renderer's
    /// per-ray outputs for it (composited over the background), the march's ranges
    /// and its samples (at least those the ranges point at). Returns how many of the
    /// rays it was marched for went opaque in it (their transmittance fell under the
    /// threshold), and how many it was marched for.
    pub fn add(&mut self, outs: &[RayOutput], ranges: &[SampleRange], samples: &[GpuSample], cap: u32) -> (usize, usize) {
        assert!(outs.len() >= self.rays.len() && ranges.len() >= self.rays.len(), "one output and range per ray");
        let (mut opaque, mut marched) = (0, 0);
        for (i, ray) in self.rays.iter_mut().enumerate() {
            if !is_active(ray) {
                continue;
            }
            let (o, bg, t) = (&outs[i], self.background[i], self.transmittance[i]);
            let acc = &mut self.acc[i];
            for c in 0..3 {
                acc.rgb[c] += t * (o.rgb[c] - (1.0 - o.opacity) * bg[c]);
                acc.normal[c] += t * o.normal[c];
            }
            acc.depth += t * o.depth;
            acc.opacity += t * o.opacity;
            let t_next = t * (1.0 - o.opacity).max(0.0);
            self.transmittance[i] = t_next;
            marched += 1;
            opaque += (t_next < self.threshold) as usize;
            let range = ranges[i];
            let next_start = (range.count > 0).then(|| {
                let last = samples[(range.start + range.count - 1) as usize];
                last.t + 0.5 * last.dt
            });
            match next_start {
                Some(start) if range.count >= cap && t_next >= self.threshold && start > ray.t_min => ray.t_min = start,
                _ => ray.t_min = ray.t_max,
            }
        }
        self.used += cap;
        (opaque, marched)
    }

    /// The rays' outputs, as one pass would composite them.
    pub fn finish(self) -> Vec<RayOutput> {
        self.acc
            .into_iter()
            .zip(&self.background)
            .map(|(mut o, bg)| {
                for c in 0..3 {
                    o.rgb[c] += (1.0 - o.opacity) * bg[c];
                }
                o
            })
            .collect()
    }
}

fn is_active(ray: &GpuRay) -> bool {
    ray.t_max > ray.t_min
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::reference::{RefSample, composite};

    /// A ray of `n` samples at spacing 0.1 from t = 1: density rising along the ray,
    /// colours and normals varying per sample.
    fn ray_samples(n: usize, density: f64) -> Vec<RefSample> {
        (0..n)
            .map(|i| {
                let x = i as f64;
                RefSample {
                    rgb: [0.5 + 0.4 * (0.3 * x).sin(), 0.2 + 0.01 * x, 0.9 - 0.02 * x],
                    sigma: density * (1.0 + 0.05 * x),
                    t: 1.05 + 0.1 * x,
                    dt: 0.1,
                    normal: [(0.2 * x).cos(), (0.2 * x).sin(), 0.3],
                    ..Default::default()
                }
            })
            .collect()
    }

    fn gpu_sample(s: &RefSample) -> GpuSample {
        GpuSample { pos: [0.0; 3], t: s.t as f32, dir: [0.0, 0.0, 1.0], dt: s.dt as f32 }
    }

    /// Segments of 3, 6, 12, ... samples composited by [`SegmentedRays`] (each segment
    /// by the reference compositor, as the renderer's kernel would) give the one-pass
    /// reference's colour, opacity, depth and normal, and stop the ray where its
    /// transmittance falls under the threshold or where its samples end.
    #[test]
    fn segments_composite_to_the_one_pass_image_and_stop_at_the_threshold() {
        let bg = [0.2, 0.7, 0.4];
        let threshold = 1e-4;
        // A faint ray that never reaches the threshold, and a dense one that does.
        for (density, n, stops_early) in [(0.3, 40, false), (6.0, 200, true)] {
            let all = ray_samples(n, density);
            let one_pass = composite(&all, bg, threshold as f64).to_ray_output();
            let ray = GpuRay { origin: [0.0; 3], t_min: 1.0, dir: [0.0, 0.0, 1.0], t_max: 1.0 + 0.1 * n as f32 };
            let mut seg = SegmentedRays::new(&[ray], vec![[bg[0] as f32, bg[1] as f32, bg[2] as f32]], threshold);
            let (mut start, mut cap, mut marched) = (0usize, 3u32, 0usize);
            while seg.any_active() {
                // What the march would give: the samples of [t_min, t_max], at most `cap`.
                let t_min = seg.rays()[0].t_min as f64;
                let first = all.iter().position(|s| s.t > t_min).unwrap_or(n);
                assert_eq!(first, start, "the next segment starts after the last sample");
                let part = &all[first..(first + cap as usize).min(n)];
                let out = composite(part, bg, threshold as f64).to_ray_output();
                let samples: Vec<GpuSample> = part.iter().map(gpu_sample).collect();
                seg.add(&[out], &[SampleRange { start: 0, count: part.len() as u32 }], &samples, cap);
                start += part.len();
                marched += part.len();
                cap *= 2;
            }
            let o = seg.finish().remove(0);
            for c in 0..3 {
                assert!((o.rgb[c] - one_pass.rgb[c]).abs() < 2e-4, "{density}: rgb {:?} vs {:?}", o.rgb, one_pass.rgb);
                assert!((o.normal[c] - one_pass.normal[c]).abs() < 2e-4, "{density}: normal {:?} vs {:?}", o.normal, one_pass.normal);
            }
            assert!((o.opacity - one_pass.opacity).abs() < 2e-4, "{density}: opacity {} vs {}", o.opacity, one_pass.opacity);
            assert!((o.depth - one_pass.depth).abs() < 2e-3, "{density}: depth {} vs {}", o.depth, one_pass.depth);
            if stops_early {
                assert!(marched < n / 2, "{density}: {marched} of {n} samples marched");
            } else {
                assert_eq!(marched, n, "{density}: a faint ray is marched to its end");
            }
        }
    }
}
