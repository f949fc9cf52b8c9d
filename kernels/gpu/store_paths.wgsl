// Benchmark of the ways a kernel can write vec4 values at per-invocation addresses
// (owner: the ignored test `store_paths_on_this_adapter` in engine/src/gpu/kernel.rs),
// the companion of load_paths.wgsl. The pattern is that of the grid backward's
// `store_rows`: straight-line code, outside any branch, each invocation writing
// ROWS consecutive vec4 of its own sample-major row. Into a storage buffer, a
// storage texture (rgba32f texels, row-major over TEXTURE_WIDTH columns) and
// workgroup memory. `to_nothing` computes the same values and writes one: the cost
// of the values themselves.

const ROWS: u32 = 16u;
const TEXTURE_WIDTH: u32 = 2048u;

@group(0) @binding(0) var<storage, read_write> rows: array<vec4<f32>>;
@group(0) @binding(1) var rows_texture: texture_storage_2d<rgba32float, write>;
@group(0) @binding(2) var<storage, read_write> sink: array<vec4<f32>>;

var<workgroup> rows_shared: array<vec4<f32>, 1024>;

// The value invocation `t` writes to its row `j`.
fn row_value(t: u32, j: u32) -> vec4<f32> {
    let x = f32(t);
    return vec4<f32>(x + f32(j), x * 0.5 - f32(j), x * 0.25, f32(j) * x);
}

fn to_buffer(t: u32, j: u32) {
    rows[t * ROWS + j] = row_value(t, j);
}

fn to_texel(t: u32, j: u32) {
    let k = t * ROWS + j;
    textureStore(rows_texture, vec2<u32>(k % TEXTURE_WIDTH, k / TEXTURE_WIDTH), row_value(t, j));
}

fn to_shared(local: u32, t: u32, j: u32) {
    rows_shared[local * ROWS + j] = row_value(t, j);
}

@compute @workgroup_size(64)
fn to_nothing(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    var acc = vec4<f32>(0.0);
    for (var j = 0u; j < ROWS; j++) {
        acc += row_value(t, j);
    }
    // Never true: the values must be computed, but nothing is written.
    if (acc.x < 0.0) {
        sink[0] = acc;
    }
}

@compute @workgroup_size(64)
fn to_storage(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    to_buffer(t, 0u); to_buffer(t, 1u); to_buffer(t, 2u); to_buffer(t, 3u);
    to_buffer(t, 4u); to_buffer(t, 5u); to_buffer(t, 6u); to_buffer(t, 7u);
    to_buffer(t, 8u); to_buffer(t, 9u); to_buffer(t, 10u); to_buffer(t, 11u);
    to_buffer(t, 12u); to_buffer(t, 13u); to_buffer(t, 14u); to_buffer(t, 15u);
}

@compute @workgroup_size(64)
fn to_texture(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    to_texel(t, 0u); to_texel(t, 1u); to_texel(t, 2u); to_texel(t, 3u);
    to_texel(t, 4u); to_texel(t, 5u); to_texel(t, 6u); to_texel(t, 7u);
    to_texel(t, 8u); to_texel(t, 9u); to_texel(t, 10u); to_texel(t, 11u);
    to_texel(t, 12u); to_texel(t, 13u); to_texel(t, 14u); to_texel(t, 15u);
}

@compute @workgroup_size(64)
fn to_workgroup(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let t = gid.x;
    to_shared(local, t, 0u); to_shared(local, t, 1u); to_shared(local, t, 2u); to_shared(local, t, 3u);
    to_shared(local, t, 4u); to_shared(local, t, 5u); to_shared(local, t, 6u); to_shared(local, t, 7u);
    to_shared(local, t, 8u); to_shared(local, t, 9u); to_shared(local, t, 10u); to_shared(local, t, 11u);
    to_shared(local, t, 12u); to_shared(local, t, 13u); to_shared(local, t, 14u); to_shared(local, t, 15u);
    workgroupBarrier();
    // One read back, so the writes are not dead; never true.
    let v = rows_shared[(local * 7u) % 1024u];
    if (v.x < 0.0) {
        sink[0] = v;
    }
}
