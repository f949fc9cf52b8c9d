//! The hash-grid field (Instant-NGP style): a multiresolution hash encoding, a density
//! MLP and a colour MLP without biases, analytic normals, and the exact backward pass
//! including the second-order path through the normals.
//!
//! Owns `kernels/field/grid_lib.wgsl` (shared bindings 0..2 and per-sample math), the
//! code generated per configuration for the per-sample kernels ([`codegen`]),
//! `grid_density.wgsl`, `grid_forward.wgsl`, `grid_backward.wgsl`, `grid_outer.wgsl`
//! and `grid_finalize.wgsl`, their bind layouts and launches; the CPU reference of the
//! whole forward (and, for the tests, backward) pass is [`reference`](mod@reference).
//!
//! # Encoding
//! Space: `p = (x - aabb_min) / (aabb_max - aabb_min)`. The AABB is the scene's content
//! box: object-centric (blender, DTU, synthetic) or the NDC cube `[-1, 1]^3` for LLFF.
//! A point outside it is **clamped** to the box for the encoding and gets **zero
//! density and a zero normal**; its colour is still evaluated (harmless: its rendering
//! weight is zero), so nothing outside the box can hold density.
//!
//! Level `l = 0 .. L-1` (`L` levels, `F = 2` features, `T = 2^log2_hashmap_size`):
//! ```text
//! b    = exp((ln N_max - ln N_min) / (L - 1))          (b = 1 when L = 1)
//! s_l  = N_min b^l - 1     pos = p s_l + 1/2     c = floor(pos)     f = pos - c
//! w_B(f) = prod_d (B_d ? f_d : 1 - f_d)                 B in {0,1}^3, the 8 corners
//! R_l  = floor(s_l + 1/2) + 2 vertices per axis; dense index x + R (y + R z) when
//!        R_l^3 <= T (the level then stores R_l^3 entries), otherwise the spatial hash
//!        (x * 1 ^ y * 2654435761 ^ z * 805459861) mod T (T entries)
//! e_{l,f} = mu_l sum_B w_B(f) F_l[i_B, f]               mu_l = [l < active levels]
//! J_{(l,f),d} = de_{l,f}/dx_d = mu_l sum_B dw_B/df_d F_l[i_B, f] s_l / extent_d
//! ```
//! `e` has `in_dim = 2L` entries, zero-padded to `in_pad` (a multiple of 4).
//! Coarse-to-fine annealing sets the active levels ([`GridField::set_active_levels`]).
//!
//! # MLPs (tiny-cuda-nn "FullyFusedMLP" without biases; width `W`, default 64)
//! ```text
//! z1 = W1 e   a1 = relu(z1)   h = W2 a1 (16)   sigma = [inside] act(h0 + density_bias)
//! xc = [h, SH_4(d)] (32)   ac1 = relu(C1 xc)   ac2 = relu(C2 ac1)   o = C3 ac2   rgb = sigmoid(o)
//! ```
//! `act` is `trunc_exp` (forward `exp(min(h0, 80))`, derivative `exp(clamp(h0, -15, 15))`
//! as Instant-NGP) or `softplus`; `density_bias` is a constant of the config (0 by
//! default). `SH_4` is the real spherical-harmonics basis of
//! degree 4 (16 terms, tiny-cuda-nn constants) of the unit view direction; the terms above
//! band [`GridConfig::sh_degree`] are zero (0: a view-independent colour).
//!
//! # Analytic normals (no finite differences)
//! ```text
//! m = relu'(z1) in {0,1}^W (relu'(0) = 0)      g = dh0/de = W1^T (m * W2[0,:])
//! v = J_beta^T g = sum_l beta_l J_l^T g_l      u = act'(h0) v
//! n = -u / |u|   (0 if |u| <= eps)
//! ```
//! `J_beta = diag(beta) J` is the Jacobian with level `l`'s rows weighted by `beta_l`
//! ([`GridConfig::normal_level_weights`], or 1 up to the resolution
//! [`GridConfig::normal_max_resolution`] and 0 above; every `beta_l = 1` by default,
//! and then `u = grad_x sigma` exactly).
//!
//! ## Band-limited normals
//! With `beta_l < 1` on the finest levels, `u` is the gradient of the density in which
//! level `l` is read at `x + beta_l dx` (`d/d dx` at `dx = 0`): the finest levels,
//! whose cells are a few pixels wide and whose gradient is per-cell noise
//! (Neuralangelo's observation), stop steering the normal, while density and colour
//! keep every level. The backward below holds with `J` read as `J_beta` throughout
//! (the same code, `s_l` scaled by `beta_l` in the normal path's `dF` term).
//!
//! ## Dense normal levels
//! A hashed level (`R_l^3 > T`) shares each entry among about `R_l^3 / T` vertices, so
//! the gradient of its trilinear interpolation jumps wherever a colliding vertex's
//! update moved the shared features: noise in the normal that no smoothness term can
//! remove without also flattening the geometry. With
//! [`GridConfig::dense_normal_levels`] every level with `beta_l > 0` is stored densely
//! (`R_l^3` entries, indexed `x + R (y + R z)` as the levels that fit `T`), and the
//! hashed levels are those that only shape density and colour. Nothing else changes:
//! the kernels and the reference read `dense_res` per level.
//!
//! # Backward (per sample; c = dL/dn, everything else standard back-propagation)
//! ```text
//! colour:  d_o = dL/drgb * rgb (1 - rgb);  dac2 = C3^T d_o * m2;  dac1 = C2^T dac2 * m1
//!          dxc = C1^T dac1;  dh = dxc[0..16]
//! density: dh0 += [inside] dL/dsigma act'(h0)
//! normal:  du = -(I - n n^T) c / |u|            (derivative of -u/|u|)
//!          dv = act'(h0) du;  dh0 += act''(h0) <v, du>   (= 0 analytically: du is
//!          orthogonal to u, the normal is scale invariant; computed anyway)
//!          dL/dJ = g (x) dv  ->  J is linear in the features:
//!              dF_l[i_B, f] += mu_l g_{l,f} <dw_B/df, dv * beta_l s_l / extent>
//!          dg = J dv  ->  g = W1^T (m * W2[0,:]) with m piecewise constant:
//!              dW1 += (m * W2[0,:]) (x) dg        dW2[0,j] += m_j (W1 dg)_j
//! first order: d1 = W2^T dh * m;  dW2 += dh (x) a1;  dW1 += d1 (x) e;  de = W1^T d1
//!          dF_l[i_B, f] += mu_l w_B(f) de_{l,f}
//! ```
//! No gradient flows to the position or the direction.
//!
//! # Kernels and performance design
//! * `forward`: one thread per sample, fully fused (encode, both MLPs, normal).
//! * `backward`: one thread per sample of a chunk: recomputes the forward pass (the
//!   encoding read from the kept region when the training forward kept it, see below),
//!   back-propagates, scatters the hash-feature gradients with `atomicAddF32` (as
//!   Instant-NGP; combined per corner and feature, zeros skipped) and writes the layer
//!   inputs/deltas to a scratch buffer (sample-major rows, 11 regions).
//! * `outer`: weight gradients as sums of outer products over the chunk: one thread per
//!   (8x8 weight tile, group of [`GridConfig::outer_samples_per_thread`] samples)
//!   accumulates in registers and adds its partials with atomics: one atomic per weight
//!   per group. The normal path's two weight terms share `M = sum_s m_s (x) dg_s` (one
//!   more product, with the ReLU mask), turned into `dW1 += diag(W2[0,:]) M` and
//!   `dW2[0,j] += <W1[j,:], M[j,:]>` by `finalize` once per backward call. All the
//!   products of a chunk (five matrices and `M`) are **one launch**: thread `t` belongs
//!   to the last product whose first thread is at most `t` (`OuterParams::products`).
//!   On an H200 that made the demo's plain steps 1.27x faster and sparse-small's 1.31x
//!   than six launches (docs/journal.md, "On an H200: the weight gradients in one launch"): the
//!   products are small, and launched one after another each waited for the last.
//! * **The kept encoding** ([`GridConfig::keep_encoding`], on by default): the forward
//!   of a training step ([`Field::forward_for_backward`], codegen's `ForwardKeep`)
//!   writes each sample's encoding `e` and the normal path's Jacobian rows (`6 L`
//!   floats, packed) to a region of the backward's scratch buffer indexed by sample
//!   (`R_KEPT`, `4 + 12` vec4s at 8 levels: 256 bytes a sample), and the backward that
//!   follows (`BackwardKept`) reads them instead of gathering the 8 corners of every
//!   level from the table again: the backward's only random accesses left are the
//!   gradient scatter's. The region lives in the scratch buffer because the backward
//!   already binds 8 storage buffers, the portable limit. The field remembers which
//!   batch, levels and normal path the rows were written for and uses them once; any
//!   other backward recomputes (`Backward`), with the same gradients in float-atomic
//!   order (`field_grid_backward_from_the_kept_encoding`). Measured on lavapipe
//!   (`edgenerf speed`, 2-core CPU, 2026-11-26, old and new binaries interleaved):
//!   the demo's backward 114-116 -> 108 ms, its forward 33-34 -> 37.6 ms (the rows'
//!   writes), sparse-small's backward unchanged: a wash on the CPU, where the
//!   backward's cost is the scatter (above). The Jacobian rows are written and read
//!   only when the pass computes normals.
//! * The batch is processed in chunks of at most [`GridConfig::backward_chunk`] samples
//!   so the scratch (2000 bytes per sample at the default width) stays under the
//!   storage binding limit (128 MiB on lavapipe); on a GPU the presets' batches fit one.
//! * The per-sample kernels read the MLP weights from a uniform-buffer copy of
//!   `grid.mlp` (refreshed by a buffer copy of at most 46 KB at the start of each
//!   pass): every thread reads the same weight at the same time, which is a broadcast
//!   from the constant cache on NVIDIA; on lavapipe the field's forward and backward
//!   are 1.5-1.7x faster than with storage reads (`field_grid_throughput`). The weights are the only uniform
//!   buffer (see `gpu::kernel`, "Uniform buffers").
//! * **Weights in workgroup memory** (2026-11-27, ninth stop). Each workgroup of the
//!   three per-sample kernels first copies the first [`SHARED_WEIGHTS4`] vec4 of that
//!   uniform block (16 KB, the workgroup memory every WebGPU device has: all 800 of the
//!   presets' width-32 field, 1024 of the default field's 2880) to workgroup memory
//!   (`wsh`, codegen's `load_shared_weights`, then a barrier; density queries copy only
//!   W1 and W2's first row, all they read), and the generated products read them from
//!   there at constant indices. On lavapipe (Mesa 22.3) every
//!   component read from a uniform or storage buffer is a bounds-checked branch, even
//!   at a constant address, while a workgroup read at a constant address outside any
//!   branch is one load and a broadcast: a chain of four 32x32 products on the 2-core
//!   CPU took 5.0-6.2 cycles per multiply-add of an 8-lane subgroup with the weights in
//!   a uniform or storage buffer, 1.35-1.47 with the copy, and 0.8-1.9 with the weights
//!   as literal constants (a timing-only kernel). For the same reason every product
//!   runs outside the kernels' branches: `g = dh0/de` is computed at the top level in
//!   the forward and the backward, also when no normal is wanted (a branch is masked
//!   straight-line code on lavapipe, so it cost its full price anyway). Measured with
//!   `edgenerf speed --kernels` (three interleaved rounds, ms a step, before -> after):
//!   the demo's forward 29.6-35.1 -> 18.1-19.7, its per-sample backward 49.0-55.3 ->
//!   37.4-52.6; sparse-small's forward 37.8-40.4 -> 23.2-25.1, backward 69.0-77.0 ->
//!   53.9-57.5; `outer` unchanged. With the copy but the normal path's product still
//!   inside its branch (reading the uniform block there), the forward took 0.75x its
//!   time and the backward the same as before. On a GPU this is tiny-cuda-nn's layout
//!   (weights staged in shared memory); it is not yet timed on one
//!   ([`GridConfig::workgroup_weights`] off reads every weight from the uniform block,
//!   for that comparison).
//!   On a CPU adapter whose workgroup memory allows it (lavapipe: 32 KB) the forward
//!   kernels (the forward, the training forward, density queries) copy
//!   [`SHARED_WEIGHTS4_CPU_FORWARD`] vec4 instead (2026-11-27, tenth stop;
//!   [`WorkgroupWeights4`], `forward_copy4`), so a width-64 field's products read all
//!   but its last 64-320 weight vec4 from the copy: at synthetic-small's field (12
//!   levels, width 64) the training forward took 216-285 against 302-372 ms a step
//!   (`edgenerf speed --kernels`, three interleaved rounds). The backward keeps
//!   [`SHARED_WEIGHTS4`]: with the larger copy the default field's backward with
//!   normals took 1153-1337 against 907-1617 ms of CPU (median 1270 against 957; five
//!   interleaved rounds of `field_grid_throughput`; five more rounds on 2026-11-28
//!   found the two the same, 860-1027 against 870-963: thirteenth finding below),
//!   while its forward with normals took 280-443 against 397-567 ms, faster in every
//!   round. GPUs keep 16 KB for every kernel (untimed there).
//! * **Specialized per configuration** ([`codegen`]): the vector code of the three
//!   per-sample kernels (encode, the MLP products, the normal's `g` and `J^T g`, the
//!   backward products, the scatter, the scratch stores) is generated for the layout in
//!   use, with widths, level counts and weight offsets as constants, so every index into
//!   a per-sample array is a constant (the arrays become registers) and every weight
//!   read is at a constant offset (one broadcast load). The kernels have no early
//!   return: a thread past the count recomputes a valid sample and writes nothing, so
//!   the hot code never runs under lavapipe's execution mask. Measured by
//!   `field_grid_throughput_small` (the presets' field: 8 levels, width 32) on the
//!   2-core CPU with lavapipe, M samples per CPU-second before -> after: forward 0.50
//!   -> 1.1, forward with normals 0.42 -> 1.09, backward 0.16 -> 0.30, backward with
//!   normals 0.15 -> 0.30, density queries 1.9 -> 3.6. At Instant-NGP's width 64 and 16
//!   levels (`field_grid_throughput`) the forward is unchanged (0.16) and the backward
//!   1.2-1.3x faster: there the unrolled products spill.
//!   A warp-cooperative (tiny-cuda-nn "fully fused") formulation with weights in
//!   workgroup memory is the next optimisation for NVIDIA.
//! * **Where the backward's time goes on lavapipe** (`edgenerf speed --preset demo`,
//!   2-core CPU, 2026-11-26; 68 k samples per step, backward 110 ms of a 165 ms step):
//!   the per-sample kernel takes about 80 ms and the `outer` products about 30 ms.
//!   Generating the kernel without the hash-feature scatter (8 corners x 2 features per
//!   active level) makes the per-sample kernel about 2.8x faster, but also the *forward*
//!   (34 -> 12 ms), which does not scatter: with the parameters frozen at their
//!   initial values and the same samples, the forward ran 34 ms after backward passes
//!   that scattered and 18 ms after ones that did not. So part of the scatter's cost
//!   is what its 8.7 M random writes a step do to the memory state the next kernels
//!   read (not denormals: flush-to-zero forced on lavapipe's threads changed nothing;
//!   `perf` shows the same forward code taking 2.6x the CPU time). It is not the
//!   atomics as such: plain loads and stores in their place (racy, timing only) ran no
//!   faster, because llvmpipe executes every scattered access lane by lane, atomic or
//!   not. Two measured dead ends: aggregating equal
//!   entries across the subgroup first (`subgroupMin` / `subgroupAdd`, one atomic per
//!   distinct entry) made the demo's backward 2x slower, and aggregating only the
//!   first lane's entry saved nothing; consecutive samples of a ray share a cell only
//!   on the two or three coarsest levels at this sample spacing. What would cut the
//!   scatter is fewer scattered accesses per sample (a per-ray pass accumulating a
//!   cell's corners over the consecutive samples inside it), not cheaper ones.
//!   A third dead end (2026-11-26, later; demo, backward 107 ms in the same
//!   invocation): a *staged table*, features and gradient interleaved as `(f0, f1, g0,
//!   g1)` per entry so that each corner's gather and scatter touch one cache line,
//!   copied in before the backward and out after it. The backward kernels then took
//!   99 ms, but the two copies of the 0.4 M entries cost more than that saved (113 ms
//!   in all), so it is not kept. A timing-only variant that gathered from the
//!   gradient buffer itself (one 3.2 MB array touched instead of two) took 88 ms: the
//!   bytes the random accesses span set the backward's cost. The forward's are not
//!   bound the same way: a timing-only forward gathering every other entry (half the
//!   bytes spanned, what a half-precision table would give) ran as fast as the real
//!   one (29-32 ms for 65 k samples, `field_grid_throughput_small`). Nor is it the
//!   scratch's 85 MB a step (1232 bytes per sample at width 32) falling out of cache
//!   between the per-sample kernel and the outer products: chunks of 4096 or 8192
//!   samples (5-10 MB of scratch) made the backward slower (145 and 134 ms against
//!   122 ms in one chunk, one invocation; `field.backward_chunk`).
//!   A fourth (2026-11-27): 16x16 weight tiles in `outer` (half the scratch loads per
//!   FMA, 256 accumulators a thread) ran 45-59 ms a step against 44 ms for the 8x8
//!   tiles (`edgenerf speed --kernels`, sparse-small), because 256 accumulators a
//!   thread spill; its atomics are not its cost (without them, timing only, 38 / 32 /
//!   45 ms against 55 / 37 / 36), its scratch loads are: a timing-only `outer` that
//!   makes its rows from the sample index ran 10-11 ms against 32-37 ms. They are
//!   per-invocation loads inside a loop, lane by lane on llvmpipe; a texture fetch is
//!   1.2-1.5x faster there and a uniform buffer 2.5-3x, but capped at 64 KB (the
//!   ignored benchmark `load_paths_on_this_adapter` in `gpu/kernel.rs`). The
//!   same tool split the scatter by level (timing-only variants, 4 levels active):
//!   the three dense coarse levels cost 17-19 ms, the one hashed level 13 ms, so the
//!   random footprint sets it, not contention between threads on hot coarse entries.
//!   And a forward that computes the corner indices but loads nothing is only about
//!   8 ms (a sixth) faster: the table gathers are not the forward's cost either.
//!   A fifth (2026-11-27, later), for Instant-NGP's default field, whose 48 MB table
//!   does not fit the caches: a level's 8 table entries computed first and their loads
//!   issued back to back before the corner arithmetic (so the misses overlap), in the
//!   forward and in the scatter, and the gradient lines read before the atomic adds.
//!   Two interleaved rounds of `edgenerf speed --kernels` measured no difference
//!   beyond the machine's noise (docs/journal.md, "Instant-NGP's default field"); not kept.
//!   A sixth (2026-11-27, fifth stop), for the same field's TLB misses: lavapipe's
//!   buffers on transparent huge pages (`GLIBC_TUNABLES=glibc.malloc.hugetlb=1`, which
//!   makes glibc ask for them; up to 280 MB of huge pages seen during the run), three
//!   interleaved rounds of `field_grid_throughput`: forward with normals 343-377 ms
//!   of CPU without, 350-363 with; backward with normals 900-1040 against 890-937.
//!   Within the noise: page walks are not what the 48 MB table's misses cost.
//! * **What lavapipe makes of these kernels** (2026-11-27, sixth stop; Mesa 22.3.6,
//!   LLVM 15; the JIT code dumped with `gdb` from a running `edgenerf speed --preset
//!   demo` and its hot spots from `perf record -p`): 94 % of the process's samples
//!   are in JIT code; the forward's and the backward's machine code are 385 KB and
//!   466 KB of straight-line code, run once per 8-sample subgroup, about 80 k
//!   instructions for 8 samples where the arithmetic needs about 30 k. The largest
//!   share is spill traffic (`vmovaps` to and from a 33 KB stack frame, the hottest
//!   instruction class, about 29 % of the forward's samples; LLVM keeps the whole
//!   32-wide activation vectors live and uses the AVX-512 registers 16-31 too). Next
//!   is every storage access with a per-invocation address: llvmpipe emits it lane by
//!   lane, each lane about 10 instructions (the lane's index from the stack, the
//!   buffer's size, a bounds-check branch, a masked broadcast load, a jump), the
//!   jumps after the table gathers taking about 6 % of the forward's samples (their
//!   cache misses land there). Products and sums are separate `vmulps` / `vaddps`
//!   (llvmpipe does not fuse them); `LP_NUM_THREADS=1` against 2 scales 1.8-2x (no
//!   cross-core effect); `LP_NATIVE_VECTOR_WIDTH=512` (16 lanes) ran the same.
//!   Three more dead ends followed from it, each timed with `edgenerf speed --kernels
//!   --preset demo` against the same build without it, interleaved, three rounds:
//!   - seventh, an `outer` whose workgroup shares one sample group and one block of
//!     uniform-side indices (the uniform side's row at an address the same for every
//!     invocation, the other side one scalar per invocation): 187-207 ms against
//!     32-36 ms. A storage load at a subgroup-uniform address inside a loop is still
//!     run lane by lane in this Mesa (only uniform-buffer loads become one load and a
//!     broadcast), so the row cost 32 lane-by-lane loads where the 8x8 tiles cost 4
//!     vec4 ones; without any loads (timing only) the same kernel took 15 ms;
//!   - eighth, the generated MLP products as explicit `fma` chains (vec4 of 4 rows
//!     per chain, so every product and sum is one `vfmadd`): forward 39-41 against
//!     39-44 ms, backward 70-88 against 72-97 ms, within the noise; not kept, since it
//!     changes the rounding for nothing;
//!   - ninth, the scatter's two features of a corner added with one 64-bit
//!     compare-exchange loop (`atomic<u64>`, which lavapipe and naga support) instead
//!     of two float atomics: backward 86-137 against 72-92 ms. A timing-only variant
//!     with a single float atomic per corner saved 13 % of the backward (64-70 against
//!     75-93 ms), but the 64-bit loop costs what the halved count saves.
//!
//!   A tenth (2026-11-27, eighth stop), against the spills: the kernels' statements
//!   reordered so that fewer values are live across the MLPs. In the forward the
//!   normal (the last use of the Jacobian rows and of `a1`) computed before the colour
//!   MLP; in the backward each scratch row stored as soon as it is final and the
//!   normal path run before the colour MLP, instead of all rows stored at the end.
//!   Same results; `field_grid_throughput_small`, interleaved, CPU ms: forward 66-77
//!   before, 70-90 after (three rounds); the backward's per-sample kernel 85.7 / 91.9
//!   against 83.4 / 87.7 ms (`edgenerf speed --kernels --preset demo`, two rounds)
//!   and 210-370 against 210-380 ms in eight rounds of the benchmark. Within the
//!   noise at best: LLVM schedules the straight-line code by its own measure of
//!   pressure, and llvmpipe runs an `if` as masked straight-line code, so a block
//!   moved inside one still splits the code where it stands. Not kept.
//!
//!   An eleventh (2026-11-27, ninth stop, before the weights moved to workgroup
//!   memory): kernels with the normal path compiled out (the flag a constant `false`)
//!   ran the same as the real ones, normals on or off (`field_grid_throughput_small`:
//!   forward 0.94 against 0.94-1.03 M samples per CPU-second, backward first order
//!   0.25 against 0.25-0.29). Not kept. The same benchmark with the encoding computed
//!   from the position (no table reads, no corner loop) and the scatter cut to one
//!   atomic per level (timing only) bounded what the table side costs: forward with
//!   normals 1.04-1.23 against 0.98, backward with normals 0.44-0.46 against 0.27-0.29.
//!   Removing the colour MLP's middle product from that forward made it 1.45x faster,
//!   which led to the weights' workgroup copy above.
//!
//!   A twelfth (2026-11-27, tenth stop) split the presets' backward after that copy
//!   (`field_grid_throughput_small`, backward with normals, timing-only variants, six
//!   interleaved rounds, each variant's fastest round in CPU ms): the real kernels 212;
//!   without the weight-gradient launch (`outer`) 175; without the per-sample rows'
//!   stores 165; without the hash-feature scatter 155. So the scatter is about 27 %,
//!   the rows' stores 22 % and `outer` (mostly its loads of those rows) 17 %: two
//!   thirds of the backward are per-invocation memory accesses, which this Mesa runs
//!   lane by lane, and the arithmetic left is about 70 ms. #14's 5x needs about 120 ms
//!   here; dropping the rows and `outer` altogether would leave about 128. The copy of
//!   the weights costs little (a kernel copying them twice ran the same, five rounds),
//!   and so does wgpu's zero-initialisation of workgroup memory (off: within the
//!   noise). A trap for timing-only variants: a copy of part of the weights leaves the
//!   rest zero, which zeroes the deltas and so skips the scatter's atomics (zero
//!   coefficients are not added); such a variant ran 1.4x faster for that alone.
//!   The same stop timed the default field's forward with each level's gathers
//!   confined to half its entries (timing only: the bytes a half-precision table would
//!   span, 32 of its 64 MB): forward with normals 273-410 against 253-477 ms of CPU
//!   (`field_grid_throughput`, five interleaved rounds, after the larger forward copy).
//!   The table's cache misses do not set that forward either, so a half-precision
//!   table would not bring it near 5x on lavapipe.
//!
//!   A thirteenth (2026-11-28, eleventh stop): could the rows reach `outer` by a
//!   cheaper path? A texture would make `outer`'s loads 1.2-1.5x faster (above), but
//!   the rows would then be written as texels. The ignored benchmark
//!   `store_paths_on_this_adapter` (`gpu/kernel.rs`, `kernels/gpu/store_paths.wgsl`)
//!   writes 16 vec4 per invocation at per-invocation addresses, straight-line as
//!   `store_rows` does (three rounds of 4 M vec4, idle machine): a storage buffer took
//!   1.53-1.64 ns per vec4, a storage texture 2.91-2.95 and workgroup memory 1.80-1.81
//!   (the same order with the other core busy: 3.0, 5.0-6.0, 2.7-3.4). llvmpipe writes
//!   all three lane by lane, so texel rows would cost the backward more than `outer`
//!   would save, and workgroup memory is no cheaper (and could not hold a chunk's rows,
//!   1232 bytes a sample against 32 KB, nor carry them to another launch).
//!   The same stop timed two more things at the default field (`field_grid_throughput`,
//!   backward with normals, interleaved, CPU ms): the fifth dead end's read of each
//!   corner's gradient line before its atomic adds, redone with the loaded values kept
//!   alive (a timing-only use, so LLVM cannot drop the loads): 957-1493 against
//!   890-1137 (three rounds), no gain, so the scatter's cache misses are not what its
//!   atomics wait for; and the backward with the 32 KB copy of the forward kernels
//!   (2048 of the 2880 weight vec4 read from workgroup memory instead of 1024): 860-1027
//!   against 870-963 (five rounds, medians 883 and 923), the same, which corrects the
//!   tenth stop's "slower" (a noisier day) and says the default field's backward is not
//!   set by its weight reads either. The 16 KB copy stays: nothing to gain.
//!
//!   A fourteenth (2026-11-28, eleventh stop) bounds what kernel changes can reach on
//!   this driver. A timing-only *floor* variant keeps every product of both passes
//!   (their results summed into one store per sample, so LLVM drops none) but makes
//!   each corner's features from its entry index instead of reading the table, and
//!   drops the scatter, the rows and `outer`. CPU ms for 65 k samples
//!   (`field_grid_throughput` and `_small`; the floor and this build interleaved, three
//!   rounds; the issue's main, f239e83, from the same day's interleaved runs, docs/journal.md):
//!
//!   | field, pass | issue's main | now | floor | 5x the issue's main |
//!   |---|---|---|---|---|
//!   | presets', forward with normals | 240-427 | 40-63 | 27-30 | 48-85 |
//!   | presets', backward with normals | 557-757 | 240-270 | 43-57 | 111-151 |
//!   | default, forward with normals | 650-880 | 277-543 | 113-130 | 130-176 |
//!   | default, backward with normals | 1460-1677 | 1057-1253 | 310-583 | 292-335 |
//!
//!   So the default field's backward would miss 5x with its table reads, scatter,
//!   rows and weight gradients all free; its forward would need the 256 table reads of
//!   a sample (16 levels, 8 corners, 2 features) to cost at most a fifth of what they
//!   cost now; and the presets' backward has about 55-105 ms for all its memory
//!   traffic, where the scatter alone takes about 57 and the rows and `outer` about 84
//!   (twelfth finding).
//!   The table reads' cost is not their count: the same stop read each corner's two
//!   features as one 64-bit load (`SHADER_INT64`, an `array<u64>` view of the table;
//!   half the per-lane loads, the same results): the default field's forward with
//!   normals took 253-347 against 297-443 ms of CPU (three rounds), within the noise.
//!   Nor their order (fifth) nor the TLB (sixth). Their footprint is: with every level
//!   confined to its first 16 k entries (timing only; 2 MB of table in all instead of
//!   64, where halving it had done nothing) the default field's forward with normals
//!   took 147-240 against 263-340 ms of CPU and its backward with normals 687-893
//!   against 870-1017 (four interleaved rounds), faster in every round. So the default
//!   field's passes wait on cache misses of a table that is larger than this CPU's
//!   caches, which no kernel change removes; even at 2 MB its forward would only reach
//!   the bar's edge (147-240 against the 130-176 the bar allows).
//!
//! # Invariants
//! * Parameters: two `f32` buffers, `grid.table` (`2 x entries`, entry-major) and
//!   `grid.mlp` (`W1 [W][in_pad] | W2 [16][W] | C1 [W][32] | C2 [W][W] | C3 [4][W]`,
//!   row-major, vec4-aligned). Padding (columns of W1 past `2L`, row 3 of C3) is zero
//!   at creation and on import and never receives gradient; exports strip it.
//! * Gradient buffers have the parameters' lengths; every pass adds to them.
//! * Initialisation is deterministic for a seed: table uniform(-r, r) (r = 1e-4),
//!   MLP layers Xavier-uniform (as tiny-cuda-nn).

mod codegen;
pub mod reference;
#[cfg(test)]
pub(crate) mod tests;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::{Field, FieldError, NamedArray, ParamGroup};
use std::sync::{Arc, OnceLock};

use crate::gpu::{BindResource, Binding, Encoder, Gpu, GpuBuffer, GpuError, IndirectArgs, Kernel, KernelSpec};
use crate::optim::WeightDecay;
use crate::rng::SplitMix64;
use crate::layout::{FieldGrads, FieldOutputs, LiveSamples, SampleBatch};
use codegen::GridKernel;

/// Outputs of the density MLP (the first is the pre-activation density).
pub const DENSITY_OUT: u32 = 16;
/// Spherical-harmonics terms of the direction encoding (degree 4).
pub const SH_TERMS: u32 = 16;
/// Largest supported number of levels (the encoding has at most 64 features).
pub const MAX_LEVELS: u32 = 32;
/// Largest supported hidden width.
pub const MAX_WIDTH: u32 = 64;
/// Floats of the uniform weight block of the kernels (`MAX_WEIGHTS4` in
/// `grid_lib.wgsl`): every matrix of the largest configuration.
pub const MAX_WEIGHT_FLOATS: usize = 4 * 2880;
/// Weight vec4s the per-sample kernels copy to workgroup memory (`wsh`, declared by
/// the generated code, [`codegen`]): 16 KB, what every WebGPU device guarantees. The presets' fields
/// (width 32: 800 vec4) fit whole; a wider field reads the rest from the uniform block.
pub const SHARED_WEIGHTS4: u32 = 1024;
/// Weight vec4s the forward kernels (the forward, the training forward and density
/// queries) copy on a CPU adapter whose limit allows it: 32 KB, lavapipe's limit, which
/// holds 2048 of a width-64 field's 2240 (synthetic-small) or 2368 (the default). On
/// lavapipe that made the training forward of synthetic-small 1.2-1.4x faster; the
/// backward stays at [`SHARED_WEIGHTS4`], where the larger copy measured no faster
/// (synthetic-small, and the default field in the thirteenth finding's five rounds;
/// a first measurement had it slower there). GPUs keep [`SHARED_WEIGHTS4`]
/// (untimed there). See "Weights in workgroup memory" in the module doc.
pub const SHARED_WEIGHTS4_CPU_FORWARD: u32 = 2048;
/// Samples summed per thread by the weight-gradient kernel on a CPU adapter, where
/// llvmpipe runs each atomic lane by lane and a thread's samples cost little more than
/// its loads.
pub const SAMPLES_PER_THREAD_CPU: u32 = 256;
/// The same on a GPU, where few long-running threads leave the GPU latency-bound and
/// many short ones contend on the atomics: on an H200, 128 ran the demo, sparse-small
/// and the default field 1-5 % faster than 32, 64 or 256 (docs/journal.md, "On an H200: the
/// weight gradients in one launch").
pub const SAMPLES_PER_THREAD_GPU: u32 = 128;
/// Largest [`GridConfig::outer_samples_per_thread`].
pub const MAX_SAMPLES_PER_THREAD: u32 = 1 << 16;

/// Density activation `sigma = act(h0)`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DensityActivation {
    /// `exp`, with the derivative's argument clamped to `[-15, 15]` (Instant-NGP).
    #[default]
    TruncExp,
    Softplus,
}

/// Configuration of the hash-grid field. Defaults are Instant-NGP's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridConfig {
    /// Levels `L` (1..=32).
    pub n_levels: u32,
    /// Features per level `F`; only 2 is supported.
    pub features_per_level: u32,
    /// `log2 T`, entries per hashed level.
    pub log2_hashmap_size: u32,
    /// Coarsest resolution `N_min`.
    pub base_resolution: u32,
    /// Finest resolution `N_max`; Instant-NGP uses `2048 x aabb_scale` (the trainer
    /// scales it for large boxes).
    pub finest_resolution: f32,
    /// Hidden width of both MLPs (a multiple of 4, at most 64).
    pub hidden_width: u32,
    pub density_activation: DensityActivation,
    /// Hash-table entries start uniform in `[-r, r]`.
    pub table_init_range: f32,
    /// Seed of the deterministic initialisation.
    pub seed: u64,
    /// Normals are zero where `|grad_x sigma| <= normal_eps`.
    pub normal_eps: f32,
    /// Per-level weights `beta_l` of the analytic normal's gradient (see "Band-limited
    /// normals" in the module doc): empty for all ones (the exact density gradient),
    /// otherwise one value `>= 0` per level, coarsest first, not all zero. Density and
    /// colour always use every level.
    pub normal_level_weights: Vec<f32>,
    /// With `normal_level_weights` empty and this `> 0`: `beta_l = 1` for the levels
    /// whose resolution `N_min b^l` is at most this, 0 for the finer ones (a
    /// band-limited normal that keeps its meaning when `n_levels` changes). 0 (the
    /// default) keeps every level.
    pub normal_max_resolution: f32,
    /// Stores every level that steers the analytic normal (`beta_l > 0`) densely, with
    /// its `R_l^3` entries, also where `R_l^3 > T`: its features then never share an
    /// entry with another vertex's, so the normal carries no hash-collision noise
    /// ("Dense normal levels" in the module doc). At most [`MAX_DENSE_ENTRIES`] per
    /// level. Off by default (Instant-NGP's layout).
    pub dense_normal_levels: bool,
    /// Added to the density MLP's output before the activation, so the untrained
    /// field's density is about `act(density_bias)` everywhere (trunc_exp: 1 at 0, the
    /// Instant-NGP start). Negative values start from nearly empty space, which only
    /// the training rays fill in.
    pub density_bias: f32,
    /// Highest band of the spherical harmonics the colour MLP reads of the view
    /// direction, 0..=3: band `l` adds `2 l + 1` terms, so 3 (the default) is
    /// tiny-cuda-nn's "degree 4", 16 terms, and 0 is a view-independent colour (the
    /// constant term only). The MLP's input keeps its 16 slots; the terms above the band
    /// are zero.
    pub sh_degree: u32,
    /// Most samples per backward chunk (bounds the scratch memory: 1104 bytes a sample
    /// at the presets' field, 2000 at the default one). The chunk is also capped by the
    /// adapter's storage-binding limit (128 MiB on lavapipe: about 100 k samples at the
    /// presets' field) and by the batch's capacity. 131072 lets a GPU run the presets'
    /// batches (capacity up to 86 k samples) in one chunk: on an H200 that gave 1-5 %
    /// more steps/s than 65536 (docs/journal.md, "On an H200: the weight gradients in one
    /// launch").
    pub backward_chunk: u32,
    /// The training step's forward keeps each sample's encoding (and the normal path's
    /// Jacobian) for the backward, which then reads it instead of gathering the hash
    /// table again ("The kept encoding" in the module doc). On by default; off
    /// recomputes it (the same gradients, in float-atomic order).
    pub keep_encoding: bool,
    /// The per-sample kernels copy the first 16 KB of the MLP weights to workgroup
    /// memory (the forward kernels 32 KB on a CPU adapter that allows it) and read them
    /// there ("Weights in workgroup memory" in the module doc). On by default; off,
    /// every weight is read from the uniform block (the same results), for timing the
    /// copy on an adapter.
    pub workgroup_weights: bool,
    /// Samples each thread of the weight-gradient kernel (`outer`) sums before its
    /// atomic adds: 0 (the default) picks by adapter, [`SAMPLES_PER_THREAD_CPU`] on a
    /// CPU adapter and [`SAMPLES_PER_THREAD_GPU`] on a GPU. Fewer means more threads
    /// and more atomics; the gradients are the same up to float-atomic order.
    pub outer_samples_per_thread: u32,
    /// Optimizer hints: learning-rate multipliers and the MLP's L2 weight decay.
    pub table_lr_scale: f32,
    pub mlp_lr_scale: f32,
    pub mlp_weight_decay: f32,
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            n_levels: 16,
            features_per_level: 2,
            log2_hashmap_size: 19,
            base_resolution: 16,
            finest_resolution: 2048.0,
            hidden_width: 64,
            density_activation: DensityActivation::TruncExp,
            table_init_range: 1e-4,
            seed: 0,
            normal_eps: 1e-10,
            normal_level_weights: Vec::new(),
            normal_max_resolution: 0.0,
            dense_normal_levels: false,
            density_bias: 0.0,
            sh_degree: 3,
            backward_chunk: 1 << 17,
            keep_encoding: true,
            workgroup_weights: true,
            outer_samples_per_thread: 0,
            table_lr_scale: 1.0,
            mlp_lr_scale: 1.0,
            mlp_weight_decay: 1e-6,
        }
    }
}

impl GridConfig {
    pub fn validate(&self) -> Result<(), FieldError> {
        let err = |m: String| Err(FieldError::Config(m));
        if !(1..=MAX_LEVELS).contains(&self.n_levels) {
            return err(format!("n_levels = {} must lie in 1..={MAX_LEVELS}", self.n_levels));
        }
        if self.features_per_level != 2 {
            return err(format!("features_per_level = {}: only 2 is supported", self.features_per_level));
        }
        if !(1..=24).contains(&self.log2_hashmap_size) {
            return err(format!("log2_hashmap_size = {} must lie in 1..=24", self.log2_hashmap_size));
        }
        if self.base_resolution < 2 {
            return err(format!("base_resolution = {} must be at least 2", self.base_resolution));
        }
        if !(self.finest_resolution.is_finite() && self.finest_resolution >= self.base_resolution as f32) {
            return err(format!(
                "finest_resolution = {} must be finite and >= base_resolution = {}",
                self.finest_resolution, self.base_resolution
            ));
        }
        if self.hidden_width == 0 || !self.hidden_width.is_multiple_of(4) || self.hidden_width > MAX_WIDTH {
            return err(format!("hidden_width = {} must be a multiple of 4 in 4..={MAX_WIDTH}", self.hidden_width));
        }
        if !self.density_bias.is_finite() || self.density_bias.abs() > 20.0 {
            return err(format!("density_bias = {} must be finite and within [-20, 20]", self.density_bias));
        }
        if self.sh_degree > 3 {
            return err(format!("sh_degree = {} must be in 0..=3 (3: 16 spherical-harmonics terms, 0: a view-independent colour)", self.sh_degree));
        }
        if !(self.normal_eps >= 0.0 && self.table_init_range >= 0.0) {
            return err("normal_eps and table_init_range must be >= 0".into());
        }
        let nw = &self.normal_level_weights;
        if !nw.is_empty() {
            if nw.len() != self.n_levels as usize {
                return err(format!(
                    "normal_level_weights has {} values, expected none or one per level (n_levels = {})",
                    nw.len(),
                    self.n_levels
                ));
            }
            if !nw.iter().all(|w| w.is_finite() && *w >= 0.0) || nw.iter().all(|w| *w == 0.0) {
                return err(format!("normal_level_weights = {nw:?} must be finite and >= 0, not all zero"));
            }
        }
        let nr = self.normal_max_resolution;
        if !(nr == 0.0 || (nr.is_finite() && nr >= self.base_resolution as f32)) {
            return err(format!(
                "normal_max_resolution = {nr} must be 0 (every level) or finite and >= base_resolution = {}",
                self.base_resolution
            ));
        }
        if self.dense_normal_levels {
            let b = self.per_level_scale();
            for (l, w) in self.normal_weights().iter().enumerate() {
                let entries = level_vertices(self.base_resolution, b, l as u32).saturating_pow(3);
                if *w > 0.0 && entries > MAX_DENSE_ENTRIES {
                    return err(format!(
                        "dense_normal_levels: level {l} steers the normal and would need {entries} dense entries \
                         (at most {MAX_DENSE_ENTRIES}); narrow the normal's band (normal_max_resolution or \
                         normal_level_weights) or turn dense_normal_levels off"
                    ));
                }
            }
        }
        if self.backward_chunk < 64 {
            return err(format!("backward_chunk = {} must be at least 64", self.backward_chunk));
        }
        if self.outer_samples_per_thread > MAX_SAMPLES_PER_THREAD {
            return err(format!(
                "outer_samples_per_thread = {} must be at most {MAX_SAMPLES_PER_THREAD} (0 picks by adapter)",
                self.outer_samples_per_thread
            ));
        }
        Ok(())
    }

    /// The weight `beta_l` of every level in the analytic normal:
    /// `normal_level_weights` when set, else 1 up to `normal_max_resolution` (every
    /// level when it is 0) and 0 above.
    pub fn normal_weights(&self) -> Vec<f32> {
        if !self.normal_level_weights.is_empty() {
            return self.normal_level_weights.clone();
        }
        let b = self.per_level_scale();
        let cap = self.normal_max_resolution as f64;
        (0..self.n_levels)
            .map(|l| {
                let res = self.base_resolution as f64 * b.powi(l as i32);
                if cap == 0.0 || res <= cap * (1.0 + 1e-6) { 1.0 } else { 0.0 }
            })
            .collect()
    }

    /// Per-level scale factor `b`.
    pub fn per_level_scale(&self) -> f64 {
        if self.n_levels <= 1 {
            1.0
        } else {
            ((self.finest_resolution as f64).ln() - (self.base_resolution as f64).ln()) / (self.n_levels as f64 - 1.0)
        }
        .exp()
    }
}

/// Where level `l` lives in the table and how it is indexed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelInfo {
    /// First entry of the level.
    pub offset: u32,
    /// Entries of the level (`res^3` dense, `T` hashed).
    pub size: u32,
    /// Vertices per axis of a dense level; 0 for a hashed level.
    pub dense_res: u32,
    /// `s_l`: `pos = p * scale + 0.5`.
    pub scale: f32,
}

/// Most entries of a level stored densely because it steers the normal
/// ([`GridConfig::dense_normal_levels`]): `256^3`, 128 MiB of features.
pub const MAX_DENSE_ENTRIES: u64 = 1 << 24;

/// `s_l = N_min b^l - 1` of level `l`.
fn level_scale(base_resolution: u32, b: f64, l: u32) -> f32 {
    (base_resolution as f64 * b.powi(l as i32) - 1.0) as f32
}

/// `R_l`, the vertices per axis of level `l`.
fn level_vertices(base_resolution: u32, b: f64, l: u32) -> u64 {
    (level_scale(base_resolution, b, l) + 0.5).floor() as u64 + 2
}

/// Sizes and offsets of every parameter of a [`GridConfig`] (offsets in floats).
#[derive(Clone, Debug, PartialEq)]
pub struct GridLayout {
    pub levels: Vec<LevelInfo>,
    /// Entries of the whole table (2 floats each).
    pub table_entries: usize,
    /// Encoding width `2L` and its padding to a multiple of 4.
    pub in_dim: usize,
    pub in_pad: usize,
    pub width: usize,
    pub w1: usize,
    pub w2: usize,
    pub c1: usize,
    pub c2: usize,
    pub c3: usize,
    pub mlp_len: usize,
    /// Weight vec4s the per-sample kernels copy to workgroup memory.
    pub workgroup_weights4: WorkgroupWeights4,
}

/// Weight vec4s the per-sample kernels copy to workgroup memory (0: none, every weight
/// read from the uniform block): the forward kernels' copy and the backward's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WorkgroupWeights4 {
    /// The forward, the training forward and density queries (these copy at most the
    /// prefix they read).
    pub forward: u32,
    pub backward: u32,
}

impl GridLayout {
    pub fn new(cfg: &GridConfig) -> Result<Self, FieldError> {
        cfg.validate()?;
        let t = 1u64 << cfg.log2_hashmap_size;
        let b = cfg.per_level_scale();
        let normal_weights = cfg.normal_weights();
        let mut levels = Vec::new();
        let mut offset = 0u64;
        for l in 0..cfg.n_levels {
            let scale = level_scale(cfg.base_resolution, b, l);
            let res = level_vertices(cfg.base_resolution, b, l);
            let dense = res * res * res <= t || (cfg.dense_normal_levels && normal_weights[l as usize] > 0.0);
            let (size, dense_res) = if dense { (res * res * res, res as u32) } else { (t, 0) };
            levels.push(LevelInfo { offset: offset as u32, size: size as u32, dense_res, scale });
            offset += size;
        }
        if offset * 2 > u32::MAX as u64 {
            return Err(FieldError::Config(format!("hash table of {offset} entries is too large")));
        }
        let in_dim = 2 * cfg.n_levels as usize;
        let in_pad = in_dim.next_multiple_of(4);
        let w = cfg.hidden_width as usize;
        let d = DENSITY_OUT as usize;
        let cin = (DENSITY_OUT + SH_TERMS) as usize;
        let w1 = 0;
        let w2 = w1 + w * in_pad;
        let c1 = w2 + d * w;
        let c2 = c1 + w * cin;
        let c3 = c2 + w * w;
        let mlp_len = c3 + 4 * w;
        debug_assert!(mlp_len <= MAX_WEIGHT_FLOATS, "validated widths and levels fit the uniform weight block");
        let copy4 = if cfg.workgroup_weights { whole_block_at_most(mlp_len, SHARED_WEIGHTS4) } else { 0 };
        let workgroup_weights4 = WorkgroupWeights4 { forward: copy4, backward: copy4 };
        Ok(Self { levels, table_entries: offset as usize, in_dim, in_pad, width: w, w1, w2, c1, c2, c3, mlp_len, workgroup_weights4 })
    }

    /// The layout with the forward kernels' workgroup copy raised to `max4` weight vec4s
    /// (at most the whole block; unchanged when the copy is off).
    pub fn with_forward_copy4(mut self, max4: u32) -> Self {
        if self.workgroup_weights4.forward > 0 {
            self.workgroup_weights4.forward = whole_block_at_most(self.mlp_len, max4);
        }
        self
    }

    /// The MLP matrices as (export name, float offset, rows, cols, row stride).
    pub fn matrices(&self) -> [(&'static str, usize, usize, usize, usize); 5] {
        let (w, d, cin) = (self.width, DENSITY_OUT as usize, (DENSITY_OUT + SH_TERMS) as usize);
        [
            ("grid.density_mlp.0", self.w1, w, self.in_dim, self.in_pad),
            ("grid.density_mlp.1", self.w2, d, w, w),
            ("grid.color_mlp.0", self.c1, w, cin, cin),
            ("grid.color_mlp.1", self.c2, w, w, w),
            ("grid.color_mlp.2", self.c3, 3, w, w),
        ]
    }

    /// Floats of backward scratch per sample.
    pub fn scratch_floats_per_sample(&self) -> usize {
        4 * scratch_dims4(self).iter().sum::<u32>() as usize
    }
}

/// Name of the table parameter array / group.
pub const TABLE_NAME: &str = "grid.table";
/// Name of the MLP parameter group.
pub const MLP_NAME: &str = "grid.mlp";

// ---------------------------------------------------------------- GPU-side layouts

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuLevel {
    offset: u32,
    size: u32,
    res: u32,
    scale: f32,
}

/// Mirror of `GridParams` in `grid_lib.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GridParams {
    aabb_min: [f32; 3],
    n_levels: u32,
    inv_extent: [f32; 3],
    active_levels: u32,
    in4: u32,
    width4: u32,
    activation: u32,
    flags: u32,
    w1: u32,
    w2: u32,
    c1: u32,
    c2: u32,
    c3: u32,
    n: u32,
    chunk_start: u32,
    chunk_len: u32,
    normal_eps: f32,
    density_bias: f32,
    sh_terms: u32,
    _pad: u32,
    scratch: [[u32; 4]; 3],
    levels: [GpuLevel; MAX_LEVELS as usize],
    /// `beta_l` of level `4 i + j` at `[i][j]`.
    normal_weights: [[f32; 4]; MAX_LEVELS as usize / 4],
}

/// Products of one `outer` launch at most (`MAX_PRODUCTS` in `grid_outer.wgsl`).
const MAX_OUTER_PRODUCTS: usize = 6;

/// Mirror of `OuterProduct` in `grid_outer.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuOuterProduct {
    d_off: u32,
    d_stride: u32,
    x_off: u32,
    x_stride: u32,
    out4: u32,
    in4: u32,
    tiles_i: u32,
    tiles_o: u32,
    n_out: u32,
    mask_d: u32,
    grad_off: u32,
    grad_stride: u32,
    to_m: u32,
    first_thread: u32,
    _pad: [u32; 2],
}

/// Mirror of `OuterParams` in `grid_outer.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct OuterParams {
    chunk_start: u32,
    chunk_len: u32,
    spt: u32,
    capacity: u32,
    n_products: u32,
    threads: u32,
    _pad: [u32; 2],
    products: [GpuOuterProduct; MAX_OUTER_PRODUCTS],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FinalizeParams {
    w1: u32,
    w2: u32,
    in4: u32,
    width: u32,
}

const FLAG_NORMALS: u32 = 1;
/// Backward: `count` is a [`LiveSamples`] list, thread `t` of a chunk runs its entry.
const FLAG_LIVE: u32 = 2;

use Binding::{Params as P, ReadOnly as R, ReadWrite as RW, Uniform as U};

const DENSITY: KernelSpec =
    KernelSpec { file: "field/grid_density.wgsl", entry: "density", bindings: &[P, R, U, R, RW] };
/// params, table, weights, samples, count, rgb_density (density in w)
const SAMPLE_DENSITY: KernelSpec =
    KernelSpec { file: "field/grid_sample_density.wgsl", entry: "sample_density", bindings: &[P, R, U, R, R, RW] };
const FORWARD: KernelSpec =
    KernelSpec { file: "field/grid_forward.wgsl", entry: "forward", bindings: &[P, R, U, R, R, RW, RW] };
/// The training step's forward (codegen's `ForwardKeep`): binding 7 is the backward's
/// scratch buffer, whose kept region it writes.
const FORWARD_KEEP: KernelSpec =
    KernelSpec { file: "field/grid_forward.wgsl", entry: "forward", bindings: &[P, R, U, R, R, RW, RW, RW] };
const BACKWARD: KernelSpec = KernelSpec {
    file: "field/grid_backward.wgsl",
    entry: "backward",
    // params, table, weights, samples, count, d_rgb_density, d_normal, table_grad, scratch
    bindings: &[P, R, U, R, R, R, R, RW, RW],
};
/// params, count, scratch, mlp_grad, normal_m
const OUTER: KernelSpec = KernelSpec { file: "field/grid_outer.wgsl", entry: "outer", bindings: &[P, R, R, RW, RW] };
const FINALIZE: KernelSpec =
    KernelSpec { file: "field/grid_finalize.wgsl", entry: "finalize", bindings: &[P, R, R, RW] };

/// Scratch regions of the backward pass (see `grid_backward.wgsl`).
mod region {
    pub const E: usize = 0;
    pub const D1: usize = 1;
    pub const A1: usize = 2;
    pub const DH: usize = 3;
    pub const DG: usize = 4;
    pub const XC: usize = 5;
    pub const DC1: usize = 6;
    pub const AC1: usize = 7;
    pub const DC2: usize = 8;
    pub const AC2: usize = 9;
    pub const DO: usize = 10;
    pub const COUNT: usize = 11;
}

/// vec4s per sample of each scratch region.
fn scratch_dims4(layout: &GridLayout) -> [u32; region::COUNT] {
    let in4 = (layout.in_pad / 4) as u32;
    let w4 = (layout.width / 4) as u32;
    [in4, w4, w4, 4, in4, 8, w4, w4, w4, w4, 1]
}

/// One weight-gradient product `grad[off + o * stride + i] += sum_s d_s[o] x_s[i]`
/// over scratch regions `d` (ReLU mask of it with `mask_d`) and `x`; `grad` is the MLP
/// gradient, or the normal path's `M` with `to_m`.
struct OuterProduct {
    d: usize,
    x: usize,
    out4: u32,
    in4: u32,
    n_out: u32,
    mask_d: bool,
    to_m: bool,
    off: usize,
    stride: usize,
}

impl OuterProduct {
    fn new(d: usize, x: usize, out4: u32, in4: u32, n_out: u32, off: usize, stride: usize) -> Self {
        Self { d, x, out4, in4, n_out, mask_d: false, to_m: false, off, stride }
    }

}

struct Scratch {
    buffer: GpuBuffer<[f32; 4]>,
    chunk: u32,
    /// vec4 offset of each region.
    offsets: [u32; region::COUNT],
    /// Samples the kept region holds (0: none), and its vec4 offset (region 11 of
    /// `GridParams::scratch`).
    kept_capacity: u32,
    kept_offset: u32,
}

/// The `scratch` slot of `GridParams` holding the kept region's offset (`R_KEPT` in
/// `grid_backward.wgsl`; the generated forward reads the slot from here).
const KEPT_REGION: usize = 11;

/// What the kept region holds: the encoding of the batch whose samples are `samples`,
/// written by [`Field::forward_for_backward`] with or without the normal Jacobian, at
/// `active_levels`. The backward uses it only when its batch, levels and normal path
/// match, and consumes it.
struct KeptEncoding {
    samples: wgpu::Buffer,
    normals: bool,
    active_levels: u32,
}

// ---------------------------------------------------------------- the field

/// The hash-grid field. See the module doc.
pub struct GridField {
    config: GridConfig,
    layout: GridLayout,
    aabb: [Vec3; 2],
    active_levels: u32,
    table: GpuBuffer<f32>,
    table_grad: GpuBuffer<f32>,
    mlp: GpuBuffer<f32>,
    mlp_grad: GpuBuffer<f32>,
    /// `M = sum_s m_s (x) dg_s` of the normal path, `[W][in_pad]`.
    normal_m: GpuBuffer<f32>,
    scratch: Option<Scratch>,
    /// The encoding the last training forward kept, if any (see [`KeptEncoding`]).
    kept: Option<KeptEncoding>,
    /// Uniform copy of the MLP weights read by the per-sample kernels, refreshed from
    /// `mlp` at the start of every pass (uniform-buffer reads are broadcasts).
    mlp_uniform: wgpu::Buffer,
    /// The density, forward and backward pipelines with the vector code generated for
    /// `layout` (`codegen`), built on first use: a dispatch neither regenerates nor
    /// looks up the text.
    kernels: [OnceLock<Arc<Kernel>>; GridKernel::COUNT],
    /// Dispatch arguments of the forward and the backward's chunks, from the batch's
    /// GPU-side count (`gpu::IndirectArgs`): only the samples present are launched.
    indirect: Option<IndirectArgs>,
}

/// Initial parameters for `config` (table, MLP), as described in the module doc.
pub fn initial_params(config: &GridConfig, layout: &GridLayout) -> (Vec<f32>, Vec<f32>) {
    let mut rng = SplitMix64::new(config.seed);
    let r = config.table_init_range as f64;
    let table: Vec<f32> = (0..layout.table_entries * 2).map(|_| rng.uniform(r) as f32).collect();
    let mut mlp = vec![0.0f32; layout.mlp_len];
    for (_, off, rows, cols, stride) in layout.matrices() {
        let bound = (6.0 / (rows + cols) as f64).sqrt();
        for r in 0..rows {
            for c in 0..cols {
                mlp[off + r * stride + c] = rng.uniform(bound) as f32;
            }
        }
    }
    (table, mlp)
}

/// A workgroup copy of the weight block of `mlp_len` floats: all of it, at most `max4`
/// vec4s.
fn whole_block_at_most(mlp_len: usize, max4: u32) -> u32 {
    ((mlp_len / 4) as u32).min(max4)
}

/// The forward kernels' workgroup copy on `gpu`, in weight vec4s:
/// [`SHARED_WEIGHTS4_CPU_FORWARD`] on a CPU adapter whose workgroup memory holds it,
/// else [`SHARED_WEIGHTS4`].
fn forward_copy4(gpu: &Gpu) -> u32 {
    if gpu.adapter().is_cpu() {
        let fits = gpu.limits().max_compute_workgroup_storage_size / 16;
        SHARED_WEIGHTS4_CPU_FORWARD.min(fits).max(SHARED_WEIGHTS4)
    } else {
        SHARED_WEIGHTS4
    }
}

impl GridField {
    /// A field over the box `aabb` (`[min, max]`, world or NDC units) with the
    /// deterministic initialisation of `config.seed`.
    pub fn new(gpu: &Gpu, config: &GridConfig, aabb: [Vec3; 2]) -> Result<Self, FieldError> {
        let layout = GridLayout::new(config)?.with_forward_copy4(forward_copy4(gpu));
        if !(aabb[0].is_finite() && aabb[1].is_finite() && aabb[0].cmplt(aabb[1]).all()) {
            return Err(FieldError::Config(format!("aabb {aabb:?} must be finite with min < max")));
        }
        let (table, mlp) = initial_params(config, &layout);
        let w = layout.width;
        Ok(Self {
            config: config.clone(),
            aabb,
            active_levels: config.n_levels,
            table: GpuBuffer::from_slice(gpu, "grid table", &table)?,
            table_grad: GpuBuffer::zeros(gpu, "grid table grad", table.len())?,
            mlp: GpuBuffer::from_slice(gpu, "grid mlp", &mlp)?,
            mlp_grad: GpuBuffer::zeros(gpu, "grid mlp grad", mlp.len())?,
            normal_m: GpuBuffer::zeros(gpu, "grid normal M", w * layout.in_pad)?,
            kernels: Default::default(),
            layout,
            indirect: None,
            scratch: None,
            kept: None,
            mlp_uniform: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("grid mlp (uniform copy)"),
                size: MAX_WEIGHT_FLOATS as u64 * 4,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        })
    }

    pub fn config(&self) -> &GridConfig {
        &self.config
    }
    pub fn layout(&self) -> &GridLayout {
        &self.layout
    }
    pub fn aabb(&self) -> [Vec3; 2] {
        self.aabb
    }
    pub fn active_levels(&self) -> u32 {
        self.active_levels
    }
    /// The parameter and gradient buffers (table, MLP).
    pub fn buffers(&self) -> [(&GpuBuffer<f32>, &GpuBuffer<f32>); 2] {
        [(&self.table, &self.table_grad), (&self.mlp, &self.mlp_grad)]
    }

    /// The CPU reference model holding a copy of the current parameters (f64).
    pub fn reference(&self, gpu: &Gpu) -> Result<reference::GridModel, GpuError> {
        Ok(reference::GridModel {
            layout: self.layout.clone(),
            activation: self.config.density_activation,
            aabb: [self.aabb[0].to_array().map(f64::from), self.aabb[1].to_array().map(f64::from)],
            active_levels: self.active_levels,
            normal_eps: self.config.normal_eps as f64,
            normal_weights: self.config.normal_weights().into_iter().map(f64::from).collect(),
            density_bias: self.config.density_bias as f64,
            sh_degree: self.config.sh_degree,
            table: self.table.read(gpu)?.into_iter().map(f64::from).collect(),
            mlp: self.mlp.read(gpu)?.into_iter().map(f64::from).collect(),
        })
    }

    fn dispatch_params(&self, n: u32, flags: u32, chunk_start: u32, chunk_len: u32) -> GridParams {
        let ext = self.aabb[1] - self.aabb[0];
        let mut levels = [GpuLevel::zeroed(); MAX_LEVELS as usize];
        for (g, l) in levels.iter_mut().zip(&self.layout.levels) {
            *g = GpuLevel { offset: l.offset, size: l.size, res: l.dense_res, scale: l.scale };
        }
        let mut normal_weights = [[0.0f32; 4]; MAX_LEVELS as usize / 4];
        for (l, w) in self.config.normal_weights().into_iter().enumerate() {
            normal_weights[l / 4][l % 4] = w;
        }
        let mut scratch = [[0u32; 4]; 3];
        if let Some(s) = &self.scratch {
            for (r, off) in s.offsets.iter().enumerate() {
                scratch[r / 4][r % 4] = *off;
            }
            scratch[KEPT_REGION / 4][KEPT_REGION % 4] = s.kept_offset;
        }
        let l = &self.layout;
        GridParams {
            aabb_min: self.aabb[0].to_array(),
            n_levels: self.config.n_levels,
            inv_extent: [1.0 / ext.x, 1.0 / ext.y, 1.0 / ext.z],
            active_levels: self.active_levels.min(self.config.n_levels),
            in4: (l.in_pad / 4) as u32,
            width4: (l.width / 4) as u32,
            activation: match self.config.density_activation {
                DensityActivation::TruncExp => 0,
                DensityActivation::Softplus => 1,
            },
            flags,
            w1: (l.w1 / 4) as u32,
            w2: (l.w2 / 4) as u32,
            c1: (l.c1 / 4) as u32,
            c2: (l.c2 / 4) as u32,
            c3: (l.c3 / 4) as u32,
            n,
            chunk_start,
            chunk_len,
            normal_eps: self.config.normal_eps,
            density_bias: self.config.density_bias,
            sh_terms: reference::sh_terms(self.config.sh_degree),
            _pad: 0,
            scratch,
            levels,
            normal_weights,
        }
    }

    /// The pipeline of `spec` with the vector code generated for this field's layout
    /// (`codegen`; built once per layout and cached by the [`Gpu`]).
    fn kernel(&self, gpu: &Gpu, spec: &KernelSpec, which: GridKernel) -> Result<Arc<Kernel>, GpuError> {
        let cell = &self.kernels[which as usize];
        if let Some(k) = cell.get() {
            return Ok(k.clone());
        }
        let k = gpu.specialized_kernel(spec, codegen::source(&self.layout, which))?;
        Ok(cell.get_or_init(|| k).clone())
    }

    /// Makes sure the dispatch arguments have room for `n_chunks` chunks.
    fn ensure_indirect(&mut self, gpu: &Gpu, n_chunks: u32) {
        if self.indirect.as_ref().is_none_or(|a| a.capacity() < n_chunks) {
            self.indirect = Some(IndirectArgs::new(gpu, n_chunks));
        }
    }

    /// Makes sure a scratch buffer for chunks of up to `capacity` samples exists, with
    /// a kept region for `capacity` samples when `config.keep_encoding` is on and it
    /// fits the binding limit beside the chunks. A new buffer drops the kept encoding.
    fn ensure_scratch(&mut self, gpu: &Gpu, capacity: u32) -> Result<(), GpuError> {
        let dims = scratch_dims4(&self.layout);
        let per_sample_bytes = 16 * dims.iter().sum::<u32>() as u64;
        let limit = gpu.limits().max_storage_buffer_binding_size;
        let kept_row_bytes = 16 * codegen::kept_dims4(&self.layout) as u64;
        // The kept region may take at most half the binding; the chunks take the rest.
        let kept_capacity =
            if self.config.keep_encoding && kept_row_bytes * capacity as u64 <= limit / 2 { capacity } else { 0 };
        let by_limit = (((limit - kept_row_bytes * kept_capacity as u64) / per_sample_bytes) as u32) / 64 * 64;
        let wanted = self.config.backward_chunk.min(by_limit).min(capacity.max(1).next_multiple_of(64)).max(64);
        if self.scratch.as_ref().is_some_and(|s| s.chunk >= wanted && s.kept_capacity >= kept_capacity) {
            return Ok(());
        }
        self.scratch = None;
        self.kept = None;
        let mut offsets = [0u32; region::COUNT];
        let mut total = 0u32;
        for (o, d) in offsets.iter_mut().zip(dims) {
            *o = total;
            total += d * wanted;
        }
        let kept_offset = total;
        total += codegen::kept_dims4(&self.layout) * kept_capacity;
        let buffer = GpuBuffer::zeros(gpu, "grid backward scratch", total as usize)?;
        self.scratch = Some(Scratch { buffer, chunk: wanted, offsets, kept_capacity, kept_offset });
        Ok(())
    }

    /// The forward of `batch`, keeping its encoding for the backward when `keep`.
    fn run_forward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool, keep: bool) -> Result<(), GpuError> {
        let gpu = enc.gpu();
        let cap = batch.capacity;
        out.assert_capacity(cap, "forward: FieldOutputs");
        if keep {
            self.ensure_scratch(gpu, cap)?;
        }
        let keep = keep && self.scratch.as_ref().is_some_and(|s| s.kept_capacity >= cap);
        let kernel = if keep {
            self.kernel(gpu, &FORWARD_KEEP, GridKernel::ForwardKeep)?
        } else {
            self.kernel(gpu, &FORWARD, GridKernel::Forward)?
        };
        let flags = if normals { FLAG_NORMALS } else { 0 };
        self.ensure_indirect(gpu, 1);
        let args = self.indirect.as_ref().expect("made above");
        let (mlp_uniform, table) = (&self.mlp_uniform, &self.table.buffer);
        let params = enc.params(&self.dispatch_params(cap, flags, 0, cap));
        enc.copy(&self.mlp.buffer, mlp_uniform, self.layout.mlp_len as u64 * 4);
        args.record(enc, &batch.count.buffer, cap, cap.max(1), 1)?;
        let mut bindings: Vec<&dyn BindResource> = vec![
            &params,
            table,
            mlp_uniform,
            &batch.samples.buffer,
            &batch.count.buffer,
            &out.rgb_density.buffer,
            &out.normal.buffer,
        ];
        if keep {
            bindings.push(&self.scratch.as_ref().expect("ensured above").buffer.buffer);
        }
        args.dispatch(enc, &kernel, &bindings, 0);
        self.kept = keep.then(|| KeptEncoding {
            samples: batch.samples.buffer.clone(),
            normals,
            active_levels: self.active_levels,
        });
        Ok(())
    }
}

impl Field for GridField {
    fn kind(&self) -> &'static str {
        "grid"
    }

    fn record_density(&self, enc: &mut Encoder, points: &GpuBuffer<[f32; 4]>, count: u32, out: &GpuBuffer<f32>)
    -> Result<(), GpuError> {
        assert!(points.len() >= count as usize && out.len() >= count as usize, "density: buffers shorter than count");
        let kernel = self.kernel(enc.gpu(), &DENSITY, GridKernel::Density)?;
        let params = enc.params(&self.dispatch_params(count, 0, 0, 0));
        enc.copy(&self.mlp.buffer, &self.mlp_uniform, self.layout.mlp_len as u64 * 4);
        enc.dispatch_threads(
            &kernel,
            &[&params, &self.table.buffer, &self.mlp_uniform, &points.buffer, &out.buffer],
            count,
        );
        Ok(())
    }

    fn record_forward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError> {
        self.run_forward(enc, batch, out, normals, false)
    }

    fn record_sample_density(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs) -> Result<(), GpuError> {
        let gpu = enc.gpu();
        let cap = batch.capacity;
        out.assert_capacity(cap, "sample density: FieldOutputs");
        let kernel = self.kernel(gpu, &SAMPLE_DENSITY, GridKernel::SampleDensity)?;
        self.ensure_indirect(gpu, 1);
        let args = self.indirect.as_ref().expect("made above");
        let params = enc.params(&self.dispatch_params(cap, 0, 0, cap));
        enc.copy(&self.mlp.buffer, &self.mlp_uniform, self.layout.mlp_len as u64 * 4);
        args.record(enc, &batch.count.buffer, cap, cap.max(1), 1)?;
        let bindings: [&dyn BindResource; 6] =
            [&params, &self.table.buffer, &self.mlp_uniform, &batch.samples.buffer, &batch.count.buffer, &out.rgb_density.buffer];
        args.dispatch(enc, &kernel, &bindings, 0);
        Ok(())
    }

    fn record_forward_for_backward(&mut self, enc: &mut Encoder, batch: &SampleBatch, out: &FieldOutputs, normals: bool)
    -> Result<(), GpuError> {
        let keep = self.config.keep_encoding;
        self.run_forward(enc, batch, out, normals, keep)
    }

    fn record_backward(
        &mut self,
        enc: &mut Encoder,
        batch: &SampleBatch,
        grads: &FieldGrads,
        live: Option<&LiveSamples>,
        normal_grads: bool,
    ) -> Result<(), GpuError> {
        let gpu = enc.gpu();
        let cap = batch.capacity;
        grads.assert_capacity(cap, "backward: FieldGrads");
        // With a live list, its count takes count[0]'s place and chunk k runs the list's
        // entries k * chunk.. (FLAG_LIVE): the chunks past the list's end are empty.
        if let Some(l) = live {
            assert!(l.capacity() >= cap, "backward: live list of {} for a batch of {cap}", l.capacity());
        }
        let count = live.map_or(&batch.count.buffer, |l| &l.list.buffer);
        self.ensure_scratch(gpu, cap)?;
        let chunk = self.scratch.as_ref().expect("scratch allocated above").chunk;
        let n_chunks = cap.div_ceil(chunk).max(1);
        self.ensure_indirect(gpu, n_chunks);
        // The kept encoding serves this backward when it is of this batch, at these
        // levels, with the Jacobian if the normal path runs; it is used once.
        let kept = self.kept.take().is_some_and(|k| {
            k.samples == batch.samples.buffer && k.active_levels == self.active_levels && (k.normals || !normal_grads)
        });
        let backward = if kept {
            self.kernel(gpu, &BACKWARD, GridKernel::BackwardKept)?
        } else {
            self.kernel(gpu, &BACKWARD, GridKernel::Backward)?
        };
        let outer = gpu.kernel(&OUTER)?;
        let spt = match self.config.outer_samples_per_thread {
            0 if gpu.adapter().is_cpu() => SAMPLES_PER_THREAD_CPU,
            0 => SAMPLES_PER_THREAD_GPU,
            n => n,
        };
        let finalize = gpu.kernel(&FINALIZE)?;
        let scratch = self.scratch.as_ref().expect("scratch allocated above");
        let dims = scratch_dims4(&self.layout);
        let l = &self.layout;
        let (in4, w4) = ((l.in_pad / 4) as u32, (l.width / 4) as u32);
        let product = OuterProduct::new;
        let w = l.width as u32;
        let mut products = vec![
            product(region::D1, region::E, w4, in4, w, l.w1, l.in_pad),
            product(region::DH, region::A1, 4, w4, DENSITY_OUT, l.w2, l.width),
            product(region::DC1, region::XC, w4, 8, w, l.c1, 32),
            product(region::DC2, region::AC1, w4, w4, w, l.c2, l.width),
            product(region::DO, region::AC2, 1, w4, 3, l.c3, l.width),
        ];
        if normal_grads {
            // M = sum_s [a1_s > 0] (x) dg_s
            let m = product(region::A1, region::DG, w4, in4, w, 0, l.in_pad);
            products.push(OuterProduct { mask_d: true, to_m: true, ..m });
        }
        assert!(products.len() <= MAX_OUTER_PRODUCTS, "outer: {} products for one launch", products.len());
        let flags = (if normal_grads { FLAG_NORMALS } else { 0 }) | (if live.is_some() { FLAG_LIVE } else { 0 });
        let args = self.indirect.as_ref().expect("made above");
        if normal_grads {
            enc.clear(&self.normal_m.buffer);
        }
        enc.copy(&self.mlp.buffer, &self.mlp_uniform, self.layout.mlp_len as u64 * 4);
        args.record(enc, count, cap, chunk, n_chunks)?;
        let mut start = 0u32;
        while start < cap {
            let len = chunk.min(cap - start);
            let params = enc.params(&self.dispatch_params(cap, flags, start, len));
            args.dispatch(
                enc,
                &backward,
                &[
                    &params,
                    &self.table.buffer,
                    &self.mlp_uniform,
                    &batch.samples.buffer,
                    count,
                    &grads.rgb_density.buffer,
                    &grads.normal.buffer,
                    &self.table_grad.buffer,
                    &scratch.buffer.buffer,
                ],
                start / chunk,
            );
            // Every product of the chunk in one launch (`grid_outer.wgsl`).
            let groups = len.div_ceil(spt);
            let mut p = OuterParams {
                chunk_start: start,
                chunk_len: len,
                spt,
                capacity: cap,
                n_products: products.len() as u32,
                ..Zeroable::zeroed()
            };
            for (slot, pr) in p.products.iter_mut().zip(&products) {
                *slot = GpuOuterProduct {
                    d_off: scratch.offsets[pr.d],
                    d_stride: dims[pr.d],
                    x_off: scratch.offsets[pr.x],
                    x_stride: dims[pr.x],
                    out4: pr.out4,
                    in4: pr.in4,
                    tiles_i: pr.in4.div_ceil(2),
                    tiles_o: pr.out4.div_ceil(2),
                    n_out: pr.n_out,
                    mask_d: pr.mask_d as u32,
                    grad_off: pr.off as u32,
                    grad_stride: pr.stride as u32,
                    to_m: pr.to_m as u32,
                    first_thread: p.threads,
                    _pad: [0; 2],
                };
                p.threads += slot.tiles_o * slot.tiles_i * groups;
            }
            let pb = enc.params(&p);
            enc.dispatch_threads(
                &outer,
                &[&pb, count, &scratch.buffer.buffer, &self.mlp_grad.buffer, &self.normal_m.buffer],
                p.threads,
            );
            start += len;
        }
        if normal_grads {
            let p = FinalizeParams { w1: (l.w1 / 4) as u32, w2: (l.w2 / 4) as u32, in4, width: l.width as u32 };
            let pb = enc.params(&p);
            enc.dispatch_threads(
                &finalize,
                &[&pb, &self.mlp.buffer, &self.normal_m.buffer, &self.mlp_grad.buffer],
                l.width as u32,
            );
        }
        Ok(())
    }

    fn params(&self) -> Vec<ParamGroup<'_>> {
        vec![
            ParamGroup::new(TABLE_NAME, &self.table, &self.table_grad)
                .lr_scale(self.config.table_lr_scale)
                .eps(1e-15)
                .weight_decay(WeightDecay::None)
                .sparse(true),
            ParamGroup::new(MLP_NAME, &self.mlp, &self.mlp_grad)
                .lr_scale(self.config.mlp_lr_scale)
                .eps(1e-15)
                .weight_decay(if self.config.mlp_weight_decay > 0.0 {
                    WeightDecay::L2 { factor: self.config.mlp_weight_decay }
                } else {
                    WeightDecay::None
                }),
        ]
    }

    fn record_zero_grads(&self, enc: &mut Encoder) {
        enc.clear(&self.table_grad.buffer);
        enc.clear(&self.mlp_grad.buffer);
    }

    fn export(&self, gpu: &Gpu) -> Result<Vec<NamedArray>, GpuError> {
        let table = self.table.read(gpu)?;
        let mlp = self.mlp.read(gpu)?;
        let mut out =
            vec![NamedArray { name: TABLE_NAME.into(), shape: vec![self.layout.table_entries, 2], data: table }];
        for (name, off, rows, cols, stride) in self.layout.matrices() {
            let mut data = Vec::with_capacity(rows * cols);
            for r in 0..rows {
                data.extend_from_slice(&mlp[off + r * stride..off + r * stride + cols]);
            }
            out.push(NamedArray { name: name.into(), shape: vec![rows, cols], data });
        }
        Ok(out)
    }

    fn import(&mut self, gpu: &Gpu, arrays: &[NamedArray]) -> Result<(), FieldError> {
        let find = |name: &str, len: usize| -> Result<&NamedArray, FieldError> {
            let a = arrays
                .iter()
                .find(|a| a.name == name)
                .ok_or_else(|| FieldError::Import(format!("array {name:?} is missing")))?;
            if a.data.len() != len {
                return Err(FieldError::Import(format!("array {name:?} has {} values, expected {len}", a.data.len())));
            }
            Ok(a)
        };
        let table = find(TABLE_NAME, self.layout.table_entries * 2)?;
        let mut mlp = vec![0.0f32; self.layout.mlp_len];
        for (name, off, rows, cols, stride) in self.layout.matrices() {
            let a = find(name, rows * cols)?;
            for r in 0..rows {
                mlp[off + r * stride..off + r * stride + cols].copy_from_slice(&a.data[r * cols..(r + 1) * cols]);
            }
        }
        self.table.write(gpu, &table.data);
        self.mlp.write(gpu, &mlp);
        self.kept = None;
        Ok(())
    }

    fn encoding_levels(&self) -> u32 {
        self.config.n_levels
    }

    fn set_active_levels(&mut self, n: u32) {
        self.active_levels = n.min(self.config.n_levels);
    }

    fn finest_active_cell(&self) -> Option<f32> {
        let level = self.active_levels.clamp(1, self.config.n_levels) - 1;
        let cells = level_scale(self.config.base_resolution, self.config.per_level_scale(), level);
        (cells > 0.0).then(|| (self.aabb[1] - self.aabb[0]).min_element() / cells)
    }
}

/// The `#[repr(C)]` mirrors of this file against their WGSL structs (naga's layout).
#[cfg(test)]
mod wgsl_mirrors {
    use super::*;

    #[test]
    fn rust_mirrors_match_their_wgsl_structs() {
        crate::assert_wgsl_mirror!(GpuLevel, "field/grid_lib.wgsl", "Level", [offset, size, res, scale]);
        crate::assert_wgsl_mirror!(GridParams, "field/grid_lib.wgsl", "GridParams", [aabb_min, n_levels, inv_extent, active_levels, in4, width4, activation, flags, w1, w2, c1, c2, c3, n, chunk_start, chunk_len, normal_eps, density_bias, sh_terms, scratch, levels, normal_weights]);
        crate::assert_wgsl_mirror!(GpuOuterProduct, "field/grid_outer.wgsl", "OuterProduct", [d_off, d_stride, x_off, x_stride, out4, in4, tiles_i, tiles_o, n_out, mask_d, grad_off, grad_stride, to_m, first_thread]);
        crate::assert_wgsl_mirror!(OuterParams, "field/grid_outer.wgsl", "OuterParams", [chunk_start, chunk_len, spt, capacity, n_products, threads, products]);
        crate::assert_wgsl_mirror!(FinalizeParams, "field/grid_finalize.wgsl", "FinalizeParams", [w1, w2, in4, width]);
    }
}
