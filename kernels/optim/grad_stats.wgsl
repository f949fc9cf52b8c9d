// Layout of the gradient statistics buffer (8 x f32) written by
// optim/grad_norm.wgsl and read by optim/adam.wgsl. Mirror of the `stat` constants in
// engine/src/optim/grad.rs (owner); keep the two equal.

// ||g|| over the finite gradient elements, before value clipping.
const STAT_RAW_NORM: u32 = 0u;
// ||clamp(g, -clip_value, clip_value)|| over the finite elements (= raw norm when
// value clipping is off): the norm that norm clipping compares with max_norm.
const STAT_NORM: u32 = 1u;
// Factor applied to the value-clipped gradients: min(1, max_norm / (norm_eps + norm)),
// 1 when norm clipping is off, 0 when any element is not finite.
const STAT_SCALE: u32 = 2u;
// Number of gradient elements that are NaN or +-Inf (exact below 2^24).
const STAT_NONFINITE: u32 = 3u;
// max |g| over the finite elements, before value clipping.
const STAT_ABS_MAX: u32 = 4u;
// Value-clipping bound consumers apply before STAT_SCALE (0: off).
const STAT_CLIP_VALUE: u32 = 5u;
// 1 once the clip has been applied to the gradient buffers in place (consumers must
// then not apply it again), 0 after a fresh reduction.
const STAT_APPLIED: u32 = 6u;
// Number of words of the guard buffers (a batch's losses) that are NaN or +-Inf. Any
// makes every consumer skip the step whatever its flags: a non-finite loss changes no
// parameter, even where its gradients came out finite.
const STAT_GUARD: u32 = 7u;

// NaN and +-Inf have an all-ones exponent. A bit test, because shader compilers may
// assume floats are finite and fold `x != x` away.
fn grad_is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}
