// One-dimensional dispatch helpers shared by every kernel launched with
// `Encoder::dispatch_threads` (engine/src/gpu/kernel.rs): workgroups of WG_SIZE
// threads, the grid folded into x and y when it exceeds the per-dimension limit.

const WG_SIZE: u32 = 64u;

fn thread_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG_SIZE;
}
