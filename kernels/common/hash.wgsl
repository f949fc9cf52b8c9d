// The stateless random numbers of every kernel that draws (sampler jitter and grid
// queries, random backgrounds). Include only; mirrored bit for bit on the host by
// engine/src/rng.rs (`pcg_hash`, `rand_u32`, `unit_f32`), which the reference tests use.

// PCG hash (Jarzynski and Olano, "Hash Functions for GPU Rendering", 2020).
fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Random word number `k` of item `index` under `seed`.
fn rand_u32(seed: u32, index: u32, k: u32) -> u32 {
    return pcg_hash(pcg_hash(pcg_hash(seed) + index) + k);
}

// Uniform float in [0, 1) from the 24 high bits of a random word.
fn unit_f32(bits: u32) -> f32 {
    return f32(bits >> 8u) * (1.0 / 16777216.0);
}
