// The opacity of a sample, shared by the renderer (render/composite.wgsl) and the
// sampler's visibility pass (sampler/visibility.wgsl), which must agree on it for the
// pass to keep exactly the samples the renderer composites.

// 1 - exp(-tau) without the cancellation of small tau: the series to tau^5 (relative
// error below tau^5 / 720, under 1.4e-8 at 0.1), else the direct form.
fn alpha_of(tau: f32, trans: f32) -> f32 {
    if (tau < 0.1) {
        return tau * (1.0 - tau * (0.5 - tau * (1.0 / 6.0 - tau * (1.0 / 24.0 - tau * (1.0 / 120.0)))));
    }
    return 1.0 - trans;
}
