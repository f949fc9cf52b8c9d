// Benchmark of the three ways a kernel can read vec4 values at per-invocation
// addresses inside a loop (owner: the ignored test `load_paths_on_this_adapter` in
// engine/src/gpu/kernel.rs): a storage buffer, a uniform buffer and a sampled texture,
// each over the same 64 KB table (4096 vec4), so the figures compare the load paths'
// instructions, not memory. On lavapipe a storage load at a per-lane address inside
// control flow is a loop over the lanes; a uniform buffer or a texel fetch is a gather.
// The access pattern is that of grid_outer.wgsl: each invocation walks its own rows.

struct BenchParams {
    iters: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<storage, read> bench: BenchParams;
@group(0) @binding(1) var<storage, read> table_storage: array<vec4<f32>>;
@group(0) @binding(2) var<uniform> table_uniform: array<vec4<f32>, 4096>;
@group(0) @binding(3) var table_texture: texture_2d<f32>;
@group(0) @binding(4) var<storage, read_write> sums: array<vec4<f32>>;

// Row `s` of invocation `t`: scattered across the table, 4 consecutive vec4 from there.
fn row(t: u32, s: u32) -> u32 {
    return (t * 37u + s * 521u) & 4091u;
}

fn texel(i: u32) -> vec4<f32> {
    return textureLoad(table_texture, vec2<u32>(i & 63u, i >> 6u), 0);
}

// What every path does with the four rows it loaded. (Each entry point reads
// `bench.iters` once, before its loop: a storage read in the loop's condition would be
// lane by lane too on lavapipe and double the storage path's time.)
fn combine(acc: vec4<f32>, a: vec4<f32>, b: vec4<f32>, c: vec4<f32>, d: vec4<f32>) -> vec4<f32> {
    return acc + a * b.x + c * d.y;
}

@compute @workgroup_size(64)
fn from_storage(@builtin(global_invocation_id) gid: vec3<u32>) {
    let iters = bench.iters;
    var acc = vec4<f32>(0.0);
    for (var s = 0u; s < iters; s++) {
        let i = row(gid.x, s);
        acc = combine(acc, table_storage[i], table_storage[i + 1u], table_storage[i + 2u], table_storage[i + 3u]);
    }
    sums[gid.x] = acc;
}

@compute @workgroup_size(64)
fn from_uniform(@builtin(global_invocation_id) gid: vec3<u32>) {
    let iters = bench.iters;
    var acc = vec4<f32>(0.0);
    for (var s = 0u; s < iters; s++) {
        let i = row(gid.x, s);
        acc = combine(acc, table_uniform[i], table_uniform[i + 1u], table_uniform[i + 2u], table_uniform[i + 3u]);
    }
    sums[gid.x] = acc;
}

@compute @workgroup_size(64)
fn from_texture(@builtin(global_invocation_id) gid: vec3<u32>) {
    let iters = bench.iters;
    var acc = vec4<f32>(0.0);
    for (var s = 0u; s < iters; s++) {
        let i = row(gid.x, s);
        acc = combine(acc, texel(i), texel(i + 1u), texel(i + 2u), texel(i + 3u));
    }
    sums[gid.x] = acc;
}
