#!/usr/bin/env bash
# Runs the edgenerf binary against bad and edge-case inputs (issue 16: broken scenes,
# cameras and NumPy files, bad configs and flags, run directories that must not be
# lost; issue 52: two runs into one directory, kill -9, SIGTERM and SIGHUP, outputs
# aimed at a scene, damaged checkpoints, another scene, cameras that miss the scene)
# and prints one table row per input with its exit code and outcome:
#   clear error  the input is refused and the message says what the case expects
#   weak error   refused, but the message lacks that (vague, or names the wrong thing)
#   accepted     a bad input the binary took and ran with
#   crash        a panic (backtrace) or a signal
#   hang         still running after $TIMEOUT seconds (killed)
#   data lost    files the command had no business changing were changed
#   ok / failed  an edge case that must work (valid but unusual input): did it
# then counts per outcome. Exit status 0 when every bad input gives a clear error and
# every edge case works, 1 otherwise.
#
#   tools/check-bad-inputs.sh [BINARY]    default target/release/edgenerf
#                                         (cargo build --release -p edgenerf-tools)
# Environment: TIMEOUT seconds per input (default 300), KEEP=1 keeps the work
# directory (its path is printed), ONLY=REGEX runs the inputs whose description matches.
# Takes about 5-10 minutes on a 2-core CPU with lavapipe (a few inputs train one step).
set -uo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
bin=$(realpath "${1:-$repo/target/release/edgenerf}" 2>/dev/null) || bin=""
if [ -z "$bin" ] || [ ! -x "$bin" ]; then
    echo "no edgenerf binary at ${1:-$repo/target/release/edgenerf}: cargo build --release -p edgenerf-tools" >&2
    exit 2
fi
timeout_s=${TIMEOUT:-300}
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
export RUST_BACKTRACE=1 # a panic shows as a backtrace
work=$(mktemp -d "${TMPDIR:-/tmp}/edgenerf-bad-inputs.XXXXXX")
if [ "${KEEP:-0}" = 1 ]; then echo "work directory: $work" >&2; else trap 'rm -rf "$work"' EXIT; fi
cd "$work" || exit 2
creases=$repo/synthetic-scenes/small/creases
demo=$repo/tools/configs/demo.toml
# One quick training step: 3 views, the demo config, coarse marching, no evaluation.
FAST=(--views 3 --iters 1 --no-eval --config "$demo" --set sampler.steps_per_diagonal=48)
# The same with 2x2 patch batches and the edge-guided terms on from step 0 (edge masks read).
SPARSE=(--views 3 --iters 1 --no-eval --config "$repo/tools/configs/sparse-small.toml" --set reg.start_step=0
    --set reg.warmup_steps=0 --set sampler.steps_per_diagonal=48)

# ---------------------------------------------------------------------------- fixtures
# blender NAME [PYTHON]: a copy of creases (train views only, or with its test views
# when PYTHON is empty and TEST=1), then PYTHON run with `t` = transforms_train.json's
# dict and `r` = the scene directory; `t` is written back.
blender() {
    local name=$1 code=${2:-}
    rm -rf "$name"
    mkdir -p "$name"
    cp -r "$creases/train" "$creases/transforms_train.json" "$name/"
    if [ "${TEST:-0}" = 1 ]; then cp -r "$creases/test" "$creases/transforms_test.json" "$name/"; fi
    [ -z "$code" ] && return
    python3 - "$name" "$code" <<'PY'
import json, os, sys
r = sys.argv[1]
p = os.path.join(r, "transforms_train.json")
t = json.load(open(p))
exec(sys.argv[2])
if t is not None:
    json.dump(t, open(p + ".new", "w"))
    os.replace(p + ".new", p)
PY
}

# npy_tool: NumPy files without NumPy (stdlib only).
cat >npy_tool.py <<'PY'
import json, math, os, struct, sys, zipfile

def npy(descr, shape, body, fortran=False, version=1, header_len=None):
    d = "{'descr': '%s', 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, shape)
    h = d + " " * ((64 - (len(d) + 11 + (2 if version > 1 else 0)) % 64) % 64) + "\n"
    n = len(h) if header_len is None else header_len
    pre = b"\x93NUMPY" + bytes([version, 0]) + (struct.pack("<H", n) if version == 1 else struct.pack("<I", n))
    return pre + h.encode() + body

def f8(values, big=False):
    return struct.pack((">" if big else "<") + "%dd" % len(values), *values)

def llff_rows(n):
    rows = []
    for i in range(n):
        rows += [1, 0, 0, i * 0.1, 128, 0, 1, 0, 0, 128, 0, 0, 1, 0, 100, 2, 20]
    return [float(v) for v in rows]

def dtu_mats(n):
    out = {}
    for i in range(n):
        a = i * 0.05
        c = (2.5 * math.cos(a), 1.0, 2.5 * math.sin(a))
        norm = lambda v: [x / math.sqrt(sum(y * y for y in v)) for x in v]
        cross = lambda u, v: [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
        f = norm([-x for x in c])
        r = norm(cross(f, [0, 1, 0]))
        d = cross(f, r)
        R = [r, d, f]
        t = [-sum(R[k][j] * c[j] for j in range(3)) for k in range(3)]
        K = [[100, 0, 64], [0, 100, 64], [0, 0, 1]]
        P = [[sum(K[k][m] * (R[m] + [t[m]])[j] for m in range(3)) for j in range(4)] for k in range(3)]
        out["world_mat_%d" % i] = [v for row in P for v in row] + [0, 0, 0, 1]
        out["scale_mat_%d" % i] = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
    return out

def write_npz(path, arrays, shapes=None):
    with zipfile.ZipFile(path, "w") as z:
        for name, vals in arrays.items():
            shape = (shapes or {}).get(name, "(4, 4)")
            z.writestr(name + ".npy", npy("<f8", shape, f8([float(v) for v in vals])))

cmd = sys.argv[1]
if cmd == "llff":  # llff DIR N [variant]
    d, n, variant = sys.argv[2], int(sys.argv[3]), (sys.argv[4] if len(sys.argv) > 4 else "")
    rows = llff_rows(n)
    shape = "(%d, 17)" % n
    body = f8(rows)
    kw = {}
    if variant == "shape15":
        shape, body = "(%d, 15)" % n, f8([0.5] * (15 * n))
    elif variant == "huge":
        shape, body = "(4611686018427387904, 4)", b""
    elif variant == "truncated":
        body = body[:-8]
    elif variant == "fortran":
        kw["fortran"] = True
        body = f8([rows[r * 17 + c] for c in range(17) for r in range(n)])
    elif variant == "bigendian":
        body = f8(rows, big=True)
    elif variant == "unicode":
        shape, body = "(%d, 17)" % n, b"\0" * (8 * 17 * n)
    elif variant == "nan":
        rows[17 + 3] = float("nan"); body = f8(rows)
    elif variant == "scaled":
        rows[17] = 3.0; body = f8(rows)
    elif variant == "negbound":
        rows[15] = -1.0; body = f8(rows)
    descr = {"bigendian": ">f8", "unicode": "<U2"}.get(variant, "<f8")
    data = npy(descr, shape, body, **kw)
    if variant == "headerlen":
        data = npy("<f8", shape, body, version=2, header_len=0xFFFFFFF0)
    if variant == "garbage":
        data = b"this is not a numpy file"
    open(os.path.join(d, "poses_bounds.npy"), "wb").write(data)
elif cmd == "dtu":  # dtu DIR N [variant]
    d, n, variant = sys.argv[2], int(sys.argv[3]), (sys.argv[4] if len(sys.argv) > 4 else "")
    m = dtu_mats(n)
    shapes = {}
    if variant == "no_world3":
        del m["world_mat_3"]
    elif variant == "no_scale3":
        del m["scale_mat_3"]
    elif variant == "singular":
        m["world_mat_3"] = [0] * 16
    elif variant == "nan":
        m["world_mat_3"][0] = float("nan")
    elif variant == "shape":
        m["world_mat_3"] = [1] * 6; shapes["world_mat_3"] = "(2, 3)"
    path = os.path.join(d, "cameras.npz")
    if variant == "garbage":
        open(path, "wb").write(b"PK\x03\x04 truncated garbage")
    else:
        write_npz(path, m, shapes)
    if variant == "bigentry":
        b = bytearray(open(path, "rb").read())
        for sig, off in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
            at = b.find(sig)
            b[at + off:at + off + 4] = struct.pack("<I", 0xFFFFFFF0)
        open(path, "wb").write(bytes(b))
elif cmd == "safetensors_foreign":  # a valid safetensors file that is not a checkpoint
    header = json.dumps({"__metadata__": {"format": "pt"}, "w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}}).encode()
    open(sys.argv[2], "wb").write(struct.pack("<Q", len(header)) + header + struct.pack("<f", 1.0))
PY

# ckpt_tool: edits of a checkpoint (safetensors) as a damaged disk, a careless tool or a
# hand would make them. OP: flip (one byte of a field tensor), reshape (a 2-D field
# tensor's shape reversed, its record left), edit-config (another seed), huge (the first
# weight of each field tensor set to -7.96e37, checksums recomputed: the gradient's norm
# overflows while every value is finite).
cat >ckpt_tool.py <<'PY'
import json, struct, sys, zlib
op, src, dst = sys.argv[1:4]
b = open(src, "rb").read()
n = struct.unpack("<Q", b[:8])[0]
h = json.loads(b[8:8 + n]); data = bytearray(b[8 + n:])
meta = h["__metadata__"]
name = next(k for k, v in h.items() if k.startswith("field.") and (op != "reshape" or (len(v["shape"]) == 2 and v["shape"][0] != v["shape"][1])))
t = h[name]; o0, o1 = t["data_offsets"]
if op == "flip":
    data[o0 + 2] ^= 0x40
elif op == "reshape":
    t["shape"] = t["shape"][::-1]
elif op == "edit-config":
    c = json.loads(meta["config"]); c["train"]["seed"] = 12345; meta["config"] = json.dumps(c)
elif op == "huge":
    rec = json.loads(meta["tensors"])
    for k, v in h.items():
        if not k.startswith("field."):
            continue
        a0, a1 = v["data_offsets"]
        data[a0:a0 + 4] = struct.pack("<f", -7.96e37)
        shape = b"".join(struct.pack("<Q", d) for d in v["shape"])
        rec[k]["crc32"] = zlib.crc32(k.encode() + b"\0" + shape + bytes(data[a0:a1]))
    meta["tensors"] = json.dumps(rec)
hb = json.dumps(h).encode(); hb += b" " * (-len(hb) % 8)
open(dst, "wb").write(struct.pack("<Q", len(hb)) + hb + bytes(data))
PY

llff() { # llff NAME [variant] [folder]: 3 poses, images in images_8 (or the folder given)
    rm -rf "$1"; mkdir -p "$1/${3:-images_8}"
    for i in 0 1 2; do cp "$creases/train/r_00$i.png" "$1/${3:-images_8}/img$i.png"; done
    python3 npy_tool.py llff "$1" 3 "${2:-}"
}
dtu() { # dtu NAME [variant]: 49 views of 128x128 (pixelNeRF layout)
    rm -rf "$1"; mkdir -p "$1/image"
    for i in $(seq 0 48); do cp "$creases/train/r_000.png" "$1/image/$(printf %06d "$i").png"; done
    python3 npy_tool.py dtu "$1" 49 "${2:-}"
}
colmap() { # colmap NAME txt|bin: creases' train views as a COLMAP model (PINHOLE,
    # points on creases' box), text in NAME/sparse/0 or binary in NAME/sparse
    rm -rf "$1"; mkdir -p "$1/images"
    cp "$creases"/train/r_00[0-7].png "$1/images/"
    python3 - "$creases" "$1" "$2" <<'PY'
import json, math, os, struct, sys
src, r, kind = sys.argv[1:]
t = json.load(open(os.path.join(src, "transforms_train.json")))
imgs = []
for i, f in enumerate(t["frames"][:8]):
    m = f["transform_matrix"]
    rc = [[m[a][0], -m[a][1], -m[a][2]] for a in range(3)]          # OpenGL -> OpenCV axes
    w = [[rc[b][a] for b in range(3)] for a in range(3)]            # w2c rotation = R^T
    tv = [-sum(w[a][b] * m[b][3] for b in range(3)) for a in range(3)]
    qw = math.sqrt(max(0.0, 1 + w[0][0] + w[1][1] + w[2][2])) / 2
    q = [qw] + [math.copysign(math.sqrt(max(0.0, 1 + 2 * w[a][a] - (w[0][0] + w[1][1] + w[2][2]))) / 2, s)
                for a, s in ((0, w[2][1] - w[1][2]), (1, w[0][2] - w[2][0]), (2, w[1][0] - w[0][1]))]
    imgs.append((i + 1, q, tv, os.path.basename(f["file_path"])))
pts = [(x, y, z) for x in (-1.3, 1.3) for y in (-1.3, 1.3) for z in (-0.1, 1.0)] + [(0.0, 0.0, 0.45)]
f, c = t["fl_x"], t["cx"]
if kind == "txt":
    d = os.path.join(r, "sparse", "0"); os.makedirs(d)
    open(os.path.join(d, "cameras.txt"), "w").write(f"1 PINHOLE 128 128 {f} {f} {c} {c}\n")
    open(os.path.join(d, "images.txt"), "w").write("".join(f"{i} {' '.join(map(str, q))} {' '.join(map(str, tv))} 1 {n}\n\n" for i, q, tv, n in imgs))
    open(os.path.join(d, "points3D.txt"), "w").write("".join(f"{i + 1} {x} {y} {z} 9 9 9 0.5 1 0\n" for i, (x, y, z) in enumerate(pts)))
else:
    d = os.path.join(r, "sparse"); os.makedirs(d)
    open(os.path.join(d, "cameras.bin"), "wb").write(struct.pack("<QiiQQ4d", 1, 1, 1, 128, 128, f, f, c, c))
    b = struct.pack("<Q", len(imgs))
    for i, q, tv, n in imgs:
        b += struct.pack("<i7di", i, *q, *tv, 1) + n.encode() + b"\0" + struct.pack("<Q", 0)
    open(os.path.join(d, "images.bin"), "wb").write(b)
    b = struct.pack("<Q", len(pts)) + b"".join(struct.pack("<Q3d3BdQ", i + 1, *p, 9, 9, 9, 0.5, 0) for i, p in enumerate(pts))
    open(os.path.join(d, "points3D.bin"), "wb").write(b)
PY
}
config() { printf '%b' "$2" >"$1"; } # config FILE TEXT

# ---------------------------------------------------------------------------- running
rows=()
declare -A count
n=0
# run_case KIND EXPECT DESC -- CMD...   (GUARD=DIR|FILE: must be unchanged afterwards)
#   KIND error: a bad input: must fail with EXPECT (a fixed string) in its output
#   KIND ok:    an edge case that must work: exit 0 with EXPECT in its output
run_case() {
    local kind=$1 expect=$2 desc=$3; shift 4
    if [ -n "${ONLY:-}" ] && ! [[ $desc =~ $ONLY ]]; then return; fi
    n=$((n + 1))
    local before="" after="" rc out outcome msg
    # train.lock is left out: each run that takes a run directory's lock writes its pid there.
    [ -n "${GUARD:-}" ] && before=$(find "$GUARD" -type f ! -name train.lock -exec sha256sum {} + 2>/dev/null | sort | sha256sum)
    out="$work/case-$n.log"
    timeout -k 10 "$timeout_s" "$@" >"$out" 2>&1 </dev/null
    rc=$?
    [ -n "${GUARD:-}" ] && after=$(find "$GUARD" -type f ! -name train.lock -exec sha256sum {} + 2>/dev/null | sort | sha256sum)
    if [ $rc -eq 124 ] || [ $rc -eq 137 ]; then
        outcome="hang"
    elif LC_ALL=C grep -qE "panicked at|stack backtrace" "$out" || { [ $rc -gt 128 ] && [ "$kind" != pipe ]; }; then
        outcome="crash"
    elif [ "$before" != "$after" ]; then
        outcome="data lost"
    elif [ "$kind" = error ]; then
        if [ $rc -eq 0 ]; then outcome="accepted"; elif LC_ALL=C grep -qF -- "$expect" "$out"; then outcome="clear error"; else outcome="weak error"; fi
    elif [ "$kind" = pipe ]; then
        outcome="ok"
    else
        if [ $rc -eq 0 ] && LC_ALL=C grep -qF -- "$expect" "$out"; then outcome="ok"; else outcome="failed"; fi
    fi
    count[$outcome]=$((${count[$outcome]:-0} + 1))
    # The message: the error line and its causes (or the last line), one line, shortened.
    msg=$(LC_ALL=C grep -aE "^(error|  caused by)" "$out" | tr '\n' ' ' | sed 's/  */ /g')
    [ -z "$msg" ] && msg=$(tail -n 1 "$out")
    msg=${msg//$work\//}
    msg=${msg//|/\\|}
    [ ${#msg} -gt 220 ] && msg="${msg:0:217}..."
    rows+=("| $n | $desc | $rc | $outcome | $msg |")
    printf '%3d %-12s %s\n' "$n" "$outcome" "$desc" >&2
}

# ---------------------------------------------------------------------------- inputs
echo "building fixtures in $work ..." >&2
printf 'a file' >afile
mkdir -p empty
printf 'hello' >empty/readme.txt

# Paths and outputs
run_case error "not found" "info: a scene directory that does not exist" -- "$bin" info "$work/no/such/scene" --no-gpu
run_case error "unrecognised scene layout" "info: a directory of no known layout" -- "$bin" info empty --no-gpu
run_case error "not found" "info: a file given as the scene" -- "$bin" info afile --no-gpu
bad_utf8=$(printf 'scene\xff')
blender "$bad_utf8"
run_case error "not valid UTF-8" "train: a scene path that is not UTF-8" -- "$bin" train "$bad_utf8" --out run-utf8 "${FAST[@]}"
blender base
run_case ok "trained 1 steps" "train: an --out path that is not UTF-8 (valid)" -- "$bin" train base --out "$(printf 'out\xff')" "${FAST[@]}"
mkdir -p "$(printf 'edges\xff')"
run_case error "UTF-8" "train: an --edges directory that is not UTF-8" -- "$bin" train base --out run-edges-utf8 "${FAST[@]}" --edges "$(printf 'edges\xff')"
GUARD=afile run_case error "is a file" "train: --out is a file" -- "$bin" train base --out afile "${FAST[@]}"

# Blender / NeRF-synthetic / nerfstudio transforms
blender b-json "t = None; open(p, 'w').write('{\"camera_angle_x\": 0.7, \"frames\": [')"
run_case error "bad JSON" "blender: truncated transforms_train.json" -- "$bin" info b-json --no-gpu
blender b-nomat "del t['frames'][0]['transform_matrix']"
run_case error "transform_matrix" "blender: a frame without transform_matrix" -- "$bin" info b-nomat --no-gpu
blender b-noimg "os.remove(os.path.join(r, 'train/r_003.png'))"
run_case error "missing image" "blender: a frame whose image is missing" -- "$bin" info b-noimg --no-gpu
blender b-noframes "t['frames'] = []"
run_case error "lists no frames" "blender: no frames" -- "$bin" info b-noframes --no-gpu
blender b-f0 "t['fl_x'] = 0.0; t['fl_y'] = 0.0"
run_case error "focal length" "blender: focal length 0" -- "$bin" info b-f0 --no-gpu
blender b-fneg "t['fl_x'] = -175.0; t['fl_y'] = -175.0"
run_case error "focal length" "blender: negative focal length" -- "$bin" info b-fneg --no-gpu
blender b-angneg "del t['fl_x']; del t['fl_y']; t['camera_angle_x'] = -0.7"
run_case error "camera_angle_x" "blender: negative camera_angle_x" -- "$bin" info b-angneg --no-gpu
blender b-angbig "del t['fl_x']; del t['fl_y']; t['camera_angle_x'] = 4.0"
run_case error "camera_angle_x" "blender: camera_angle_x above pi" -- "$bin" info b-angbig --no-gpu
blender b-rot0 "m = t['frames'][0]['transform_matrix']; [m[i].__setitem__(j, 0.0) for i in range(3) for j in range(3)]"
run_case error "not orthonormal" "blender: a zero rotation" -- "$bin" info b-rot0 --no-gpu
blender b-rotscale "m = t['frames'][1]['transform_matrix']; [m[i].__setitem__(j, 2 * m[i][j]) for i in range(3) for j in range(3)]"
run_case error "not orthonormal" "blender: a rotation scaled by 2" -- "$bin" info b-rotscale --no-gpu
blender b-mirror "m = t['frames'][0]['transform_matrix']; [m[i].__setitem__(0, -m[i][0]) for i in range(3)]"
run_case error "reflection" "blender: a mirrored rotation (det -1)" -- "$bin" info b-mirror --no-gpu
blender b-bottom "t['frames'][0]['transform_matrix'][3] = [0, 0, 0, 0]"
run_case error "bottom row" "blender: bottom row 0 0 0 0" -- "$bin" info b-bottom --no-gpu
blender b-nan "d = t; t = None; d['frames'][0]['transform_matrix'][0][0] = float('nan'); open(p, 'w').write(json.dumps(d))"
run_case error "bad JSON" "blender: NaN in a transform_matrix" -- "$bin" info b-nan --no-gpu
blender b-fisheye "t['camera_model'] = 'OPENCV_FISHEYE'; t['k1'] = 0.05"
run_case ok "lens        OPENCV_FISHEYE" "nerfstudio: camera_model OPENCV_FISHEYE (valid: distorted rays)" -- "$bin" info b-fisheye --no-gpu
blender b-k1 "t['camera_model'] = 'OPENCV'; t['k1'] = 0.1"
run_case ok "lens        OPENCV k1..k4 [0.1" "nerfstudio: distortion k1 = 0.1 (valid: distorted rays)" -- "$bin" info b-k1 --no-gpu
blender b-equirect "t['camera_model'] = 'EQUIRECTANGULAR'"
run_case error "EQUIRECTANGULAR\" is not supported" "nerfstudio: camera_model EQUIRECTANGULAR" -- "$bin" info b-equirect --no-gpu
blender b-p1 "t['camera_model'] = 'OPENCV_FISHEYE'; t['frames'][2]['p1'] = 0.01"
run_case error "no tangential terms" "nerfstudio: p1 on one frame of a fisheye" -- "$bin" info b-p1 --no-gpu
blender b-isfish "t['is_fisheye'] = True"
run_case error "is_fisheye" "instant-ngp: is_fisheye true" -- "$bin" info b-isfish --no-gpu
blender b-perframe "t['frames'][0]['fl_x'] = 100.0"
run_case ok "fx 100.00 fy 100.00" "nerfstudio: per-frame fl_x is used (valid)" -- "$bin" info b-perframe --no-gpu
blender b-opencv0 "t['camera_model'] = 'OPENCV'; t.update(k1=0.0, k2=0.0, p1=0.0, p2=0.0)"
run_case ok "fx 175.84" "nerfstudio: OPENCV with zero distortion (valid)" -- "$bin" info b-opencv0 --no-gpu
blender b-nearfar "t['near'] = 6.0; t['far'] = 2.0"
run_case error "near" "blender: near above far" -- "$bin" info b-nearfar --no-gpu
blender b-aabb "t['aabb'] = [[1, 1, 1], [-1, -1, -1]]"
run_case error "aabb" "blender: aabb with min above max" -- "$bin" info b-aabb --no-gpu
blender b-size
python3 - b-size <<'PY'
# r_001.png: a 64x32 grey PNG written with zlib (no PIL needed).
import struct, sys, zlib
def chunk(k, d): return struct.pack(">I", len(d)) + k + d + struct.pack(">I", zlib.crc32(k + d) & 0xffffffff)
raw = b"".join(b"\0" + b"\x80" * 64 for _ in range(32))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 64, 32, 8, 0, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open(sys.argv[1] + "/train/r_001.png", "wb").write(png)
PY
run_case error "size mismatch" "blender: one image of another size" -- "$bin" info b-size --no-gpu
blender b-badpng "t = None; open(os.path.join(r, 'train/r_000.png'), 'wb').write(b'\\x89PNG\\r\\n\\x1a\\n garbage')"
run_case error "r_000.png" "blender: a corrupt PNG" -- "$bin" train b-badpng --out run-badpng "${FAST[@]}"
blender b-mask "t['frames'][0]['mask_path'] = '../b-size/train/r_001.png'"
run_case error "size mismatch" "blender: a mask of the wrong size" -- "$bin" train b-mask --out run-mask "${FAST[@]}"
blender b-exr "t = None; open(os.path.join(r, 'train/r_000_depth.exr'), 'wb').write(b'v/1\\x01 not an exr')"
run_case error "bad OpenEXR" "blender: a corrupt depth EXR" -- "$bin" train b-exr --out run-exr "${FAST[@]}"
blender b-noexr "t = None; os.remove(os.path.join(r, 'train/r_000_normal.exr'))"
run_case error "r_000_normal.exr" "blender: a missing normal EXR" -- "$bin" train b-noexr --out run-noexr "${FAST[@]}"
blender b-notest
run_case error "no test views" "train: a scene without transforms_test.json (with evaluation)" -- "$bin" train b-notest --out run-notest --views 3 --iters 1 --config "$demo"
TEST=1 blender b-badtest
printf '{"frames": [' >b-badtest/transforms_test.json
run_case error "transforms_test.json" "blender: truncated transforms_test.json" -- "$bin" info b-badtest --no-gpu
run_case error "training views" "info: --views 100 of 24" -- "$bin" info base --views 100 --no-gpu
run_case error "0 training views" "info: --views 0" -- "$bin" info base --views 0 --no-gpu

# LLFF and NumPy files
llff l-shape shape15
run_case error "(N, 17)" "llff: poses_bounds.npy of shape (3, 15)" -- "$bin" info l-shape --no-gpu
llff l-garbage garbage
run_case error "magic" "npy: not a NumPy file" -- "$bin" info l-garbage --no-gpu
llff l-huge huge
run_case error "more bytes than memory can hold" "npy: a header claiming shape (2^62, 4)" -- "$bin" info l-huge --no-gpu
llff l-trunc truncated
run_case error "truncated" "npy: data cut short" -- "$bin" info l-trunc --no-gpu
llff l-hlen headerlen
run_case error "truncated .npy header" "npy: a header length past the end of the file" -- "$bin" info l-hlen --no-gpu
llff l-unicode unicode
run_case error "not supported" "npy: dtype <U2" -- "$bin" info l-unicode --no-gpu
llff l-fortran fortran
run_case ok "3 of 128x128" "npy: Fortran order (valid)" -- "$bin" info l-fortran --no-gpu
llff l-big bigendian
run_case ok "3 of 128x128" "npy: big-endian float64 (valid)" -- "$bin" info l-big --no-gpu
llff l-nan nan
run_case error "row 1" "llff: NaN in a pose" -- "$bin" info l-nan --no-gpu
llff l-scaled scaled
run_case error "orthonormal" "llff: a scaled rotation" -- "$bin" info l-scaled --no-gpu
llff l-negbound negbound
run_case error "near bound" "llff: a negative near bound" -- "$bin" info l-negbound --no-gpu
llff l-factor "" images_4
run_case error "--llff-factor 4" "llff: no images_8 (images_4 present)" -- "$bin" info l-factor --no-gpu
run_case ok "3 of 128x128" "llff: --llff-factor 4 reads images_4 (valid)" -- "$bin" info l-factor --llff-factor 4 --no-gpu
run_case error "--llff-factor" "llff: --llff-factor 0" -- "$bin" info l-factor --llff-factor 0 --no-gpu
llff l-full "" images
run_case ok "3 of 16x16" "llff: no images_8, images/ downsampled by 8 on load (valid)" -- "$bin" info l-full --no-gpu
llff l-count
rm l-count/images_8/img2.png
run_case error "2 images for 3 cameras" "llff: 2 images for 3 poses" -- "$bin" info l-count --no-gpu

# COLMAP models and nerfstudio transforms.json (issue 18)
colmap c-txt txt
run_case ok "colmap (sparse model)" "colmap: a text model in sparse/0 (valid)" -- "$bin" info c-txt --no-gpu
colmap c-bin bin
run_case ok "aabb        [-1.43, -1.43, -0.155]" "colmap: a binary model in sparse/ (valid)" -- "$bin" info c-bin --no-gpu
colmap c-nocam bin
rm c-nocam/sparse/cameras.bin
run_case error "cameras.bin or cameras.txt" "colmap: no cameras.bin" -- "$bin" info c-nocam --no-gpu
colmap c-trunc bin
python3 -c "import sys; p = sys.argv[1]; b = open(p, 'rb').read(); open(p, 'wb').write(b[:len(b) // 2])" c-trunc/sparse/images.bin
run_case error "truncated" "colmap: images.bin cut in half" -- "$bin" info c-trunc --no-gpu
colmap c-model txt
sed -i 's/ PINHOLE / FISHEYE624 /' c-model/sparse/0/cameras.txt
run_case error "unknown camera model \"FISHEYE624\"" "colmap: unknown camera model" -- "$bin" info c-model --no-gpu
colmap c-full txt
sed -i 's/ PINHOLE 128 128 \([^ ]*\) \([^ ]*\) \([^ ]*\) \([^ ]*\)$/ FULL_OPENCV 128 128 \1 \2 \3 \4 0.1 0 0 0 0 0 0 0/' c-full/sparse/0/cameras.txt
run_case error "image_undistorter" "colmap: FULL_OPENCV (not supported)" -- "$bin" info c-full --no-gpu
colmap c-noimg txt
rm c-noimg/images/r_001.png
run_case error "r_001.png" "colmap: an image of the model is missing" -- "$bin" info c-noimg --no-gpu
blender n-both
echo '{"frames": []}' >n-both/transforms.json
run_case error "ambiguous" "nerfstudio: transforms.json beside transforms_train.json" -- "$bin" info n-both --no-gpu
blender n-ns "os.rename(p, os.path.join(r, 'transforms.json')); t = None"
run_case ok "nerfstudio (transforms.json)" "nerfstudio: creases' frames as one transforms.json (valid)" -- "$bin" info n-ns --no-gpu
blender n-ff "os.remove(p); p = os.path.join(r, 'transforms.json'); t['frames'] = [dict(f, transform_matrix=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]) for f in t['frames']]; [t.pop(k) for k in ('near', 'far', 'aabb')]"
run_case error "forward-facing" "nerfstudio: cameras facing one way, no points, no near" -- "$bin" info n-ff --no-gpu

# DTU
dtu d-garbage garbage
run_case error "not a valid .npz" "dtu: cameras.npz is not a zip archive" -- "$bin" info d-garbage --no-gpu
dtu d-noworld no_world3
run_case error "no world_mat_3" "dtu: world_mat_3 missing" -- "$bin" info d-noworld --no-gpu
dtu d-noscale no_scale3
run_case error "no scale_mat_3" "dtu: scale_mat_3 missing" -- "$bin" info d-noscale --no-gpu
dtu d-singular singular
run_case error "world_mat_3" "dtu: a singular world_mat" -- "$bin" info d-singular --no-gpu
dtu d-nan nan
run_case error "NaN" "dtu: NaN in a world_mat" -- "$bin" info d-nan --no-gpu
dtu d-shape shape
run_case error "expected (4, 4)" "dtu: a world_mat of shape (2, 3)" -- "$bin" info d-shape --no-gpu
dtu d-bigentry bigentry
run_case error "claims" "npz: an entry claiming 4 GiB" -- "$bin" info d-bigentry --no-gpu
dtu d-masks
mkdir -p d-masks/mask
cp "$creases/train/r_000_mask.png" d-masks/mask/000.png
run_case error "masks for 49 images" "dtu: 1 mask for 49 images" -- "$bin" train d-masks --out run-dmasks "${FAST[@]}"

# Config files and flags
config c.yaml 'train:\n  iters: 3\n'
run_case error "TOML (.toml) or JSON (.json) only" "config: --config x.yaml" -- "$bin" train base --out run-yaml --config c.yaml
run_case error "no-such.toml" "config: --config of a missing file" -- "$bin" train base --out run-missing --config no-such.toml
config c-type.toml '[train]\niters = "many"\n'
run_case error "train.iters" "config: a value of the wrong type" -- "$bin" train base --out run-type --config c-type.toml
config c-syntax.toml '[train\niters = 3\n'
run_case error "line 1" "config: TOML syntax error" -- "$bin" train base --out run-syntax --config c-syntax.toml
for section in sampler field render optim.adam optim.clip edges.canny reg regnerf priors mlp train.level_anneal; do
    config "c-$section.toml" "[$section]\nbogus_key = 1\n"
    run_case error "bogus_key" "config: an unknown key in [$section]" -- "$bin" train base --out "run-$section" --config "c-$section.toml" --no-eval
done
config c-bg.toml '[render.background]\nkind = "black"\nrgb = [1, 1, 1]\n'
run_case error "rgb" "config: a key the variant does not have (background black + rgb)" -- "$bin" train base --out run-bg --config c-bg.toml --no-eval
run_case error "unknown key" "flag: --set train.itres=5" -- "$bin" train base --out run-set --set train.itres=5
run_case error "must both be positive" "flag: --set train.rays_per_batch=0" -- "$bin" train base --out run-rpb0 "${FAST[@]}" --set train.rays_per_batch=0
run_case error "must both be positive" "flag: --set train.max_samples=0" -- "$bin" train base --out run-ms0 "${FAST[@]}" --set train.max_samples=0
run_case error "multiple of 4" "flag: --set train.rays_per_batch=6 (patch batches)" -- "$bin" train base --out run-rpb6 "${SPARSE[@]}" --set train.rays_per_batch=6
run_case error "0..=255" "flag: --tau-e 300 (a run without edge masks)" -- "$bin" train base --out run-tau "${FAST[@]}" --tau-e 300
run_case error "tau_e" "flag: --tau-e nan" -- "$bin" train base --out run-taunan "${FAST[@]}" --tau-e nan
run_case error "canny.sigma" "edges: --canny-sigma 1e9" -- "$bin" edges base --views 3 --canny-sigma 1e9 --out edges-sigma
run_case error "canny thresholds" "edges: --canny-low 2" -- "$bin" edges base --views 3 --canny-low 2 --out edges-low
run_case error "lambda_depth" "flag: --lambda-depth -1" -- "$bin" train base --out run-ld "${FAST[@]}" --lambda-depth -1
run_case error "lambda_normal" "flag: --lambda-normal nan" -- "$bin" train base --out run-ln "${FAST[@]}" --lambda-normal nan
run_case error "max_seconds" "flag: --max-seconds -1" -- "$bin" train base --out run-msn "${FAST[@]}" --max-seconds -1
run_case error "max_seconds" "flag: --max-seconds nan" -- "$bin" train base --out run-msnan "${FAST[@]}" --max-seconds nan
run_case error "iters" "flag: --iters 0" -- "$bin" train base --out run-iters0 --views 3 --iters 0 --no-eval --config "$demo"
run_case error "resolution" "flag: --set sampler.resolution=100000" -- "$bin" train base --out run-res "${FAST[@]}" --set sampler.resolution=100000
run_case error "log2_hashmap_size" "flag: --set field.log2_hashmap_size=40" -- "$bin" train base --out run-hash "${FAST[@]}" --set field.log2_hashmap_size=40
run_case error "n_levels" "flag: --set field.n_levels=0" -- "$bin" train base --out run-lv "${FAST[@]}" --set field.n_levels=0
run_case error "hidden_width" "flag: --set field.hidden_width=7" -- "$bin" train base --out run-hw "${FAST[@]}" --set field.hidden_width=7
run_case error "lr" "flag: --set optim.schedule.lr=-1" -- "$bin" train base --out run-lr "${FAST[@]}" --set optim.schedule.lr=-1
run_case error "images_per_step" "flag: --set train.images_per_step=0" -- "$bin" train base --out run-ips "${FAST[@]}" --set train.images_per_step=0
run_case error "background" "flag: --set scene.background=[2,0,0]" -- "$bin" train base --out run-sbg "${FAST[@]}" --set 'scene.background=[2,0,0]'
run_case error "transmittance_threshold" "flag: --set render.transmittance_threshold=2" -- "$bin" train base --out run-tt "${FAST[@]}" --set render.transmittance_threshold=2
run_case error "lambda_depth" "flag: --set reg.lambda_depth=-1" -- "$bin" train base --out run-rld "${FAST[@]}" --set reg.lambda_depth=-1
run_case error "start_levels" "flag: --set train.level_anneal.start_levels=0" -- "$bin" train base --out run-la "${FAST[@]}" --set train.level_anneal.start_levels=0
run_case error "patch_size" "flag: --regnerf-depth-tv with regnerf.patch_size=100000" -- "$bin" train base --out run-ps "${FAST[@]}" --regnerf-depth-tv --set regnerf.patch_size=100000
run_case error "width" "flag: --backend mlp --set mlp.width=0" -- "$bin" train base --out run-mlpw "${FAST[@]}" --backend mlp --set mlp.width=0
run_case error "adapters present" "flag: --adapter no-such-gpu" -- "$bin" --adapter no-such-gpu info base

# Run directories, checkpoints, render and eval
"$bin" train base --out run --views 3 --iters 2 --no-eval --config "$demo" --set sampler.steps_per_diagonal=48 >run.log 2>&1 || echo "fixture run failed: see $work/run.log" >&2
GUARD=run run_case error "--overwrite" "train: into a directory holding a finished run" -- "$bin" train base --out run "${FAST[@]}"
GUARD=run run_case error "cannot be used with" "train: --resume with --config" -- "$bin" train base --out run --resume --config "$demo"
GUARD=run run_case error "cannot be used with" "train: --resume with --views" -- "$bin" train base --out run --resume --views 5
GUARD=run run_case error "cannot be used with" "train: --resume with --backend mlp" -- "$bin" train base --out run --resume --backend mlp
GUARD=run run_case error "cannot be used with" "train: --resume with --set" -- "$bin" train base --out run --resume --set train.seed=2
GUARD=run run_case error "cannot be used with" "train: --resume with --overwrite" -- "$bin" train base --out run --resume --overwrite
run_case error "holds no checkpoint" "train: --resume into an empty directory" -- "$bin" train base --out empty-run --resume
GUARD=run run_case error "was trained on" "train: --resume with another scene" -- "$bin" train b-perframe --out run --resume --iters 3
GUARD=afile run_case error "is a file" "render: --out is a file" -- "$bin" render run --out afile --split train
GUARD=afile run_case error "is a file" "eval: --out is a file" -- "$bin" eval run --out afile --lpips none
run_case error "no-such-run" "render: a checkpoint that does not exist" -- "$bin" render no-such-run --out r-none
printf 'garbage' >garbage.safetensors
run_case error "not a safetensors file" "render: a checkpoint of garbage bytes" -- "$bin" render garbage.safetensors --out r-garbage
head -c 2000 run/checkpoint.safetensors >trunc.safetensors
run_case error "trunc.safetensors" "render: a truncated checkpoint" -- "$bin" render trunc.safetensors --out r-trunc
python3 npy_tool.py safetensors_foreign foreign.safetensors
run_case error "not an edgenerf checkpoint" "render: a safetensors file that is no checkpoint" -- "$bin" render foreign.safetensors --out r-foreign
blender moved
"$bin" train moved --out run-moved --views 3 --iters 1 --no-eval --config "$demo" >run-moved.log 2>&1 || echo "fixture run-moved failed" >&2
mv moved moved-away
run_case error "--scene" "render: the run's scene was moved away" -- "$bin" render run-moved --out r-moved --split train
run_case error "no test views" "render: --split test of a scene without test views" -- "$bin" render run --out r-notest --split test
run_case error "no test views" "eval: --split test of a scene without test views" -- "$bin" eval run --out e-notest --lpips none
run_case error "fetch-weights" "eval: --lpips vgg without the weights" -- env EDGENERF_LPIPS_WEIGHTS="$work/no-weights" "$bin" eval run --split train --lpips vgg --out e-lpips

# Edge maps
mkdir -p edgemaps-empty edgemaps-bad edgemaps-small
run_case error "no edge map" "edges: --edges DIR without the views' maps" -- "$bin" train base --out run-e1 "${SPARSE[@]}" --edges edgemaps-empty
for f in base/train/*.png; do b=$(basename "$f"); case $b in *_mask.png) ;; *) printf 'garbage' >"edgemaps-bad/$b" ;; esac; done
run_case error "edgemaps-bad/r_000.png" "edges: edge maps that are not images" -- "$bin" train base --out run-e2 "${SPARSE[@]}" --edges edgemaps-bad
for f in base/train/*.png; do b=$(basename "$f"); case $b in *_mask.png) ;; *) cp b-size/train/r_001.png "edgemaps-small/$b" ;; esac; done
run_case error "edgemaps-small/r_000.png" "edges: edge maps of the wrong size" -- "$bin" train base --out run-e3 "${SPARSE[@]}" --edges edgemaps-small
run_case error "no-such-edges" "edges: --edges DIR that does not exist" -- "$bin" train base --out run-e4 "${SPARSE[@]}" --edges ./no-such-edges
run_case error "no-such-edges" "edges: --edges DIR that does not exist (a run without edge masks)" -- "$bin" train base --out run-e5 "${FAST[@]}" --edges ./no-such-edges

# Monocular depth maps (--mono-depth DIR, priors.mono_depth_dir)
mkdir -p mono-empty mono-bad mono-aspect mono-colour mono-half
python3 - <<'PY'
import glob, os, struct, zlib
def npy(path, h, w):  # float32 (h, w), row-major: a disparity ramp
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d), }" % (h, w)
    header += " " * (63 - (len(header) + 10) % 64) + "\n"
    data = b"".join(struct.pack("<f", 0.2 + 0.01 * (x + y)) for y in range(h) for x in range(w))
    open(path, "wb").write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + data)
def png(path, w, h, colour):  # 8-bit grey or RGB ramp
    ch = 3 if colour else 1
    rows = b"".join(b"\x00" + bytes(((x + y) % 256 for x in range(w) for _ in range(ch))) for y in range(h))
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2 if colour else 0, 0, 0, 0)
    open(path, "wb").write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
for f in glob.glob("base/train/*.png"):
    b = os.path.basename(f)[:-4]
    if b.endswith("_mask"):
        continue
    open(f"mono-bad/{b}.npy", "wb").write(b"garbage")
    npy(f"mono-aspect/{b}.npy", 64, 100)
    png(f"mono-colour/{b}.png", 128, 128, True)
    png(f"mono-half/{b}.png", 64, 64, False)
PY
run_case error "no-such-maps" "mono depth: --mono-depth DIR that does not exist" -- "$bin" train base --out run-m1 "${FAST[@]}" --mono-depth ./no-such-maps
run_case error "no monocular depth map" "mono depth: --mono-depth DIR without the views' maps" -- "$bin" train base --out run-m2 "${FAST[@]}" --mono-depth mono-empty
run_case error "mono-bad/" "mono depth: maps that are not NumPy arrays" -- "$bin" train base --out run-m3 "${FAST[@]}" --mono-depth mono-bad
run_case error "aspect ratios differ" "mono depth: maps of another aspect ratio than the images" -- "$bin" train base --out run-m4 "${FAST[@]}" --mono-depth mono-aspect
run_case error "grey image" "mono depth: colour PNG maps" -- "$bin" train base --out run-m5 "${FAST[@]}" --mono-depth mono-colour
run_case error "priors.stereo_depth" "mono depth: priors.mono_depth_dir with the stereo depth prior off" -- "$bin" train base --out run-m6 "${FAST[@]}" --set priors.mono_depth_dir=\"mono-half\"
run_case ok "trained 1 steps" "mono depth: grey PNG maps at half the images' size (valid)" -- "$bin" train base --out run-m7 "${FAST[@]}" --mono-depth mono-half
llff l-mono
run_case error "NDC" "mono depth: --mono-depth on a forward-facing LLFF scene (NDC rays)" -- "$bin" train l-mono --out run-m8 --views 2 --iters 1 --no-eval --mono-depth mono-half

# Other commands
run_case error "no-such-suite" "bench: an unknown suite" -- "$bin" bench no-such-suite --out bench-x
run_case error "repeats" "bench: --repeats 0" -- "$bin" bench geometry --quick --repeats 0 --out bench-r0 --report-only
run_case error "steps" "speed: --steps 0" -- "$bin" speed --preset demo --steps 0 --warmup 0 --out speed-0
run_case pipe "" "info piped into head -c 1 (stdout closed early)" -- bash -c "'$bin' info base --no-gpu | head -c 1 >/dev/null"

# Faults and concurrency (issue 52): a second writer, kill -9, outputs aimed at inputs,
# damaged checkpoints, another scene, cameras that miss the scene.
# long_run DIR SCENE [ARGS]: a training run in the background until killed; waits for
# 3 logged steps; its pid in $pid.
long_run() {
    local dir=$1 scene=$2; shift 2
    "$bin" train "$scene" --out "$dir" --views 3 --iters 100000 --no-eval --config "$demo" \
        --set sampler.steps_per_diagonal=48 "$@" >"$dir.log" 2>&1 &
    pid=$!
    for _ in $(seq 1 "$timeout_s"); do
        [ -f "$dir/log.csv" ] && [ "$(wc -l <"$dir/log.csv")" -ge 4 ] && break
        sleep 1
    done
}
if [ -z "${ONLY:-}" ] || [[ "two runs|kill -9" =~ $ONLY ]]; then
    long_run run-two base --set train.checkpoint_every=1
    run_case error "is in use" "train: two runs into one --out (the second, with --overwrite)" -- "$bin" train b-perframe --out run-two "${FAST[@]}" --overwrite
    kill -KILL $pid; wait $pid 2>/dev/null
    run_case ok "trained" "train: --resume after kill -9 (no stale lock)" -- "$bin" train base --out run-two --resume --iters 40 --no-eval
    run_case ok "each step once" "train: log.csv after kill -9 and --resume" -- python3 -c '
import csv, sys
steps = [int(r["step"]) for r in csv.DictReader(open("run-two/log.csv"))]
sys.exit(print("each step once") if steps == list(range(len(steps))) else "steps logged: %s" % steps)'
fi
mkdir -p run-nockpt && cp run/config.json run/log.csv run-nockpt/
run_case error "--overwrite" "train: --resume of a run killed before its first checkpoint" -- "$bin" train base --out run-nockpt --resume
TEST=1 blender scene
GUARD=scene run_case error "is the scene directory" "train: --out SCENE --overwrite" -- "$bin" train scene --out scene --overwrite "${FAST[@]}"
GUARD=scene run_case error "lies inside the scene" "train: --out SCENE/test --overwrite" -- "$bin" train scene --out scene/test --overwrite "${FAST[@]}"
GUARD=scene run_case error "lies inside the scene" "edges: --out SCENE/train" -- "$bin" edges scene --views 3 --out scene/train
"$bin" train scene --out run-scene "${FAST[@]}" >run-scene.log 2>&1 || echo "fixture run-scene failed" >&2
GUARD=scene run_case error "lies inside the scene" "render: --out SCENE/train" -- "$bin" render run-scene --scene scene --split train --out scene/train
GUARD=scene run_case error "lies inside the scene" "eval: --out SCENE/test" -- "$bin" eval run-scene --scene scene --out scene/test --lpips none
GUARD=run-scene run_case error "is the run directory" "render: --out the run directory" -- "$bin" render run-scene --out run-scene
printf 'keep me' >existing.txt
GUARD=existing.txt run_case error "already exists" "export mesh: --out an existing file" -- "$bin" export mesh run-scene --resolution 8 --out existing.txt
run_case error "--allow-other-scene" "render: --scene another scene than the run's" -- "$bin" render run-scene --scene base --out r-other
run_case error "--allow-other-scene" "eval: --scene another scene than the run's" -- "$bin" eval run-scene --scene base --out e-other --lpips none
python3 ckpt_tool.py flip run/checkpoint.safetensors flipped.safetensors
run_case error "damaged" "render: a checkpoint with one byte flipped" -- "$bin" render flipped.safetensors --out r-flipped
python3 ckpt_tool.py reshape run/checkpoint.safetensors reshaped.safetensors
run_case error "shape" "render: a checkpoint tensor reshaped to the same size" -- "$bin" render reshaped.safetensors --out r-reshaped
python3 ckpt_tool.py edit-config run/checkpoint.safetensors edited.safetensors
run_case error "edited.safetensors" "render: a checkpoint whose config was edited" -- "$bin" render edited.safetensors --out r-edited
mkdir -p run-huge && cp run/config.json run/log.csv run-huge/
python3 ckpt_tool.py huge run/checkpoint.safetensors run-huge/checkpoint.safetensors
GUARD=run-huge/checkpoint.safetensors run_case error "training diverged" "train: --resume of a checkpoint holding weights of -8e37" -- "$bin" train base --out run-huge --resume --iters 5 --no-eval
blender b-away "[m[i].__setitem__(j, -m[i][j]) for f in t['frames'] for m in [f['transform_matrix']] for i in range(3) for j in (0, 2)]"
run_case error "no ray entered" "train: cameras that all look away from the scene" -- "$bin" train b-away --out run-away --views 3 --iters 50 --no-eval --config "$demo"
blender b-samepose "[f.__setitem__('transform_matrix', t['frames'][0]['transform_matrix']) for f in t['frames']]"
run_case error "the same camera pose" "train: every training camera at one pose" -- "$bin" train b-samepose --out run-samepose "${FAST[@]}"
blender b-clear "
import struct, zlib
def chunk(k, d): return struct.pack('>I', len(d)) + k + d + struct.pack('>I', zlib.crc32(k + d))
png = b'\\x89PNG\\r\\n\\x1a\\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', 128, 128, 8, 6, 0, 0, 0)) + chunk(b'IDAT', zlib.compress(b''.join(b'\\0' + b'\\xff\\xff\\xff\\0' * 128 for _ in range(128)))) + chunk(b'IEND', b'')
[open(os.path.join(r, 'train', n), 'wb').write(png) for n in os.listdir(os.path.join(r, 'train')) if n.endswith('.png') and not n.endswith('_mask.png')]"
run_case error "fully transparent" "train: every training image fully transparent (alpha 0)" -- "$bin" train b-clear --out run-clear "${FAST[@]}"
TEST=1 blender b-test0
python3 -c 'import json; p="b-test0/transforms_test.json"; t=json.load(open(p)); t["frames"]=[]; json.dump(t, open(p, "w"))'
"$bin" train b-test0 --out run-test0 "${FAST[@]}" >run-test0.log 2>&1 || echo "fixture run-test0 failed" >&2
run_case error "lists no frames" "render: a transforms_test.json with 0 frames" -- "$bin" render run-test0 --out r-test0
GUARD=afile run_case error "is a file" "edges: --out is a file" -- "$bin" edges base --views 3 --out afile
GUARD=afile run_case error "is a file" "bench: --out is a file" -- "$bin" bench geometry --quick --out afile --report-only

# Ctrl-C, SIGTERM (timeout, cluster schedulers) and SIGHUP (a closed terminal) during
# training: a checkpoint at the step reached, nothing lost.
for sig in INT TERM HUP; do
    desc="SIG$sig during training (must save a checkpoint)"
    if [ -n "${ONLY:-}" ] && ! [[ "$desc Ctrl-C" =~ $ONLY ]]; then continue; fi
    n=$((n + 1))
    long_run "run-$sig" base --set train.checkpoint_every=0
    kill "-$sig" $pid
    wait $pid
    rc=$?
    if grep -qE "panicked at|stack backtrace" "run-$sig.log"; then outcome="crash"
    elif [ -f "run-$sig/checkpoint.safetensors" ] && grep -qF "checkpoint saved" "run-$sig.log"; then outcome="ok"
    else outcome="data lost"; fi
    count[$outcome]=$((${count[$outcome]:-0} + 1))
    msg=$(grep -E "^error" "run-$sig.log" | head -n 1); msg=${msg//$work\//}
    rows+=("| $n | $desc | $rc | $outcome | ${msg:0:220} |")
    printf '%3d %-12s %s\n' "$n" "$outcome" "$desc" >&2
done

# ---------------------------------------------------------------------------- report
echo "edgenerf bad-input check: $bin ($(cd "$repo" && git rev-parse --short HEAD 2>/dev/null || echo unknown)), $(date -u +%Y-%m-%dT%H:%MZ), timeout ${timeout_s}s"
echo
echo "| # | input | exit | outcome | message |"
echo "|---|---|---|---|---|"
printf '%s\n' "${rows[@]}"
echo
summary="inputs $n"
for o in "clear error" "weak error" "accepted" "crash" "hang" "data lost" "ok" "failed"; do
    summary+=", $o ${count[$o]:-0}"
done
echo "$summary"
bad=$(( ${count[weak error]:-0} + ${count[accepted]:-0} + ${count[crash]:-0} + ${count[hang]:-0} + ${count[data lost]:-0} + ${count[failed]:-0} ))
[ $bad -eq 0 ]
