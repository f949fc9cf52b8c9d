// Buffer layouts shared by sampler, field and renderer kernels. Mirror of
// engine/src/layout.rs (see its module doc for the invariants); keep the two equal.

struct Ray {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
}

struct SampleRange {
    start: u32,
    count: u32,
}

struct Sample {
    pos: vec3<f32>,
    t: f32,
    dir: vec3<f32>,
    dt: f32,
}

struct RayOutput {
    rgb: vec3<f32>,
    opacity: f32,
    normal: vec3<f32>,
    depth: f32,
}

// Per-ray side output of the renderer's forward pass, read by its backward pass and
// by the photometric loss (the background composited behind the ray).
struct RayAux {
    background: vec3<f32>,
    n_contrib: u32,
    // The ray's unweighted distortion D, occlusion O and orientation R (render/composite.wgsl).
    distortion: f32,
    occlusion: f32,
    orientation: f32,
    // Input (the caller writes it, the forward keeps it): the stereo free-space prior's
    // end, the ray parameter before which density is penalised (0: none).
    free_end: f32,
}

// LiveSamples (engine/src/layout.rs): one u32 list whose count sits in count[0]'s
// place; the index of the k-th live sample is at LIVE_HEADER + k.
const LIVE_HEADER: u32 = 4u;
