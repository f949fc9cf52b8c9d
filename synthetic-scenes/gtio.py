"""Minimal, dependency-free (NumPy + zlib) readers and writers for the files the
synthetic scenes ship: 8-bit PNG (gray, RGB, RGBA) and scanline OpenEXR with
float32 channels and ZIP compression.

Written here (rather than taken from Mitsuba's Bitmap) so that the bytes we commit
are fully determined by this code: fixed zlib level, fixed header, no timestamps.
The reader handles exactly what the writer produces (plus uncompressed and ZIPS
EXRs), which is all the drift check needs.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

ZLIB_LEVEL = 9

# --------------------------------------------------------------------------- PNG

_PNG_SIG = b"\x89PNG\r\n\x1a\n"
_PNG_COLOR = {1: 0, 3: 2, 4: 6}  # channels -> PNG colour type (gray, RGB, RGBA)


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def write_png(path: str | Path, img: np.ndarray) -> None:
    """Writes an 8-bit PNG. `img` is uint8, shape (H, W) or (H, W, C), C in {1, 3, 4}.

    Rows are filtered with the PNG 'Up' or 'Sub' filter (whichever compresses the
    row better by a cheap estimate), then deflated at a fixed level: deterministic.
    """
    a = np.asarray(img)
    if a.dtype != np.uint8:
        raise ValueError("write_png expects uint8")
    if a.ndim == 2:
        a = a[:, :, None]
    h, w, c = a.shape
    if c not in _PNG_COLOR:
        raise ValueError(f"unsupported channel count {c}")
    rows = a.reshape(h, w * c).astype(np.int16)
    prev = np.vstack([np.zeros((1, w * c), np.int16), rows[:-1]])
    up = (rows - prev) & 0xFF
    left = np.hstack([np.zeros((h, c), np.int16), rows[:, :-c]])
    sub = (rows - left) & 0xFF
    paeth = (rows - _paeth(left, prev, np.hstack([np.zeros((h, c), np.int16), prev[:, :-c]]))) & 0xFF
    cands = [(0, rows & 0xFF), (1, sub), (2, up), (4, paeth)]

    def cost(x: np.ndarray) -> np.ndarray:  # sum of |signed byte| per row (libpng heuristic)
        s = x.astype(np.int16)
        return np.minimum(s, 256 - s).sum(axis=1)

    costs = np.stack([cost(x) for _, x in cands])
    best = costs.argmin(axis=0)
    raw = bytearray()
    for y in range(h):
        ftype, data = cands[best[y]]
        raw.append(ftype)
        raw += data[y].astype(np.uint8).tobytes()
    ihdr = struct.pack(">IIBBBBB", w, h, 8, _PNG_COLOR[c], 0, 0, 0)
    out = _PNG_SIG + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(bytes(raw), ZLIB_LEVEL))
    out += _png_chunk(b"IEND", b"")
    Path(path).write_bytes(out)


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    p = a + b - c
    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def read_png(path: str | Path) -> np.ndarray:
    """Reads an 8-bit non-interlaced PNG (gray, gray+alpha, RGB, RGBA) to uint8 (H, W, C)."""
    data = Path(path).read_bytes()
    if data[:8] != _PNG_SIG:
        raise ValueError(f"{path}: not a PNG")
    pos, idat, hdr = 8, bytearray(), None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        tag = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + n]
        pos += 12 + n
        if tag == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat += body
        elif tag == b"IEND":
            break
    assert hdr is not None
    w, h, depth, ctype, _, _, interlace = hdr
    if depth != 8 or interlace != 0 or ctype not in (0, 2, 4, 6):
        raise ValueError(f"{path}: unsupported PNG (depth {depth}, type {ctype}, interlace {interlace})")
    c = {0: 1, 2: 3, 4: 2, 6: 4}[ctype]
    raw = np.frombuffer(zlib.decompress(bytes(idat)), np.uint8).reshape(h, 1 + w * c)
    out = np.zeros((h, w * c), np.int32)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        prev = out[y - 1] if y > 0 else np.zeros(w * c, np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) & 0xFF
        elif f in (1, 3, 4):
            cur = np.zeros(w * c, np.int32)
            for x in range(w * c):
                a = cur[x - c] if x >= c else 0
                b = prev[x]
                if f == 1:
                    pred = a
                elif f == 3:
                    pred = (a + b) // 2
                else:
                    cc = prev[x - c] if x >= c else 0
                    p = a + b - cc
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - cc)
                    pred = a if (pa <= pb and pa <= pc) else (b if pb <= pc else cc)
                cur[x] = (line[x] + pred) & 0xFF
        else:
            raise ValueError(f"{path}: bad PNG filter {f}")
        out[y] = cur
    return out.astype(np.uint8).reshape(h, w, c)


# --------------------------------------------------------------------------- EXR


def round_mantissa(x: np.ndarray, bits: int) -> np.ndarray:
    """Rounds float32 values to `bits` significant bits (1 implicit + bits-1 stored),
    round-half-up on the magnitude; zero stays zero. Makes float data compressible."""
    a = np.ascontiguousarray(x, np.float32)
    drop = 24 - bits
    if drop <= 0:
        return a.copy()
    i = a.view(np.uint32).astype(np.uint64)
    i = ((i + (1 << (drop - 1))) >> drop) << drop
    return i.astype(np.uint32).view(np.float32).reshape(a.shape)


_EXR_MAGIC = 20000630
_EXR_FLOAT = 2
_EXR_COMPRESSION = {"none": 0, "zips": 2, "zip": 3, "pxr24": 5}
_LINES_PER_BLOCK = {0: 1, 2: 1, 3: 16, 5: 16}


def _attr(name: str, typ: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(value)) + value


def _zip_encode(raw: bytes) -> bytes:
    b = np.frombuffer(raw, np.uint8)
    t = np.concatenate([b[0::2], b[1::2]]).astype(np.int16)
    d = t.copy()
    d[1:] = (t[1:] - t[:-1] + 128) & 0xFF
    return zlib.compress(d.astype(np.uint8).tobytes(), ZLIB_LEVEL)


def _zip_decode(comp: bytes, size: int) -> bytes:
    d = np.frombuffer(zlib.decompress(comp), np.uint8).astype(np.int64)
    if d.size != size:
        raise ValueError("EXR: bad ZIP block size")
    t = (np.cumsum(d - np.r_[0, np.full(d.size - 1, 128)]) & 0xFF).astype(np.uint8)
    half = (size + 1) // 2
    out = np.empty(size, np.uint8)
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def float_to_f24(x: np.ndarray) -> np.ndarray:
    """OpenEXR's PXR24 rounding of float32 to its top 24 bits (sign, exponent, 15
    mantissa bits), returned as uint32 in [0, 2^24). Matches floatToFloat24."""
    u = np.ascontiguousarray(x, np.float32).view(np.uint32).astype(np.uint64)
    s, e, m = u & 0x80000000, u & 0x7F800000, u & 0x007FFFFF
    finite = e != 0x7F800000
    i = ((e | m) + (m & 0x80)) >> 8
    i = np.where(i >= 0x7F8000, (e | m) >> 8, i)
    nan_or_inf = (e >> 8) | (m >> 8) | ((m != 0) & ((m >> 8) == 0))
    i = np.where(finite, i, nan_or_inf)
    return ((s >> 8) | i).astype(np.uint32)


def _pxr24_encode(block: np.ndarray) -> bytes:
    """block: float32 (lines, channels, width). Per line and channel: 24-bit values,
    differences to the previous pixel, split into three byte planes; then zlib."""
    f24 = float_to_f24(block).astype(np.int64)
    prev = np.concatenate([np.zeros(f24.shape[:-1] + (1,), np.int64), f24[..., :-1]], -1)
    diff = (f24 - prev) & 0xFFFFFF
    planes = np.stack([(diff >> 16) & 0xFF, (diff >> 8) & 0xFF, diff & 0xFF], -2)  # (l, c, 3, w)
    return zlib.compress(planes.astype(np.uint8).tobytes(), ZLIB_LEVEL)


def _pxr24_decode(comp: bytes, lines: int, nch: int, w: int) -> np.ndarray:
    planes = np.frombuffer(zlib.decompress(comp), np.uint8).reshape(lines, nch, 3, w).astype(np.uint64)
    diff = (planes[:, :, 0] << 16) | (planes[:, :, 1] << 8) | planes[:, :, 2]
    f24 = np.cumsum(diff, axis=-1) & 0xFFFFFF
    return (f24 << 8).astype(np.uint32).view(np.float32)


def write_exr(path: str | Path, channels: dict[str, np.ndarray], compression: str = "zip") -> None:
    """Writes a single-part scanline OpenEXR with float32 channels.

    `channels` maps a channel name ("Y", or "R", "G", "B") to an (H, W) array.
    Channels are stored in alphabetical order, as the format requires.
    """
    names = sorted(channels)
    arrays = [np.ascontiguousarray(channels[n], dtype="<f4") for n in names]
    h, w = arrays[0].shape
    if any(a.shape != (h, w) for a in arrays):
        raise ValueError("all EXR channels must have the same shape")
    comp = _EXR_COMPRESSION[compression]
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", _EXR_FLOAT, 0, 1, 1) for n in names) + b"\0"
    box = struct.pack("<iiii", 0, 0, w - 1, h - 1)
    header = struct.pack("<ii", _EXR_MAGIC, 2)
    header += _attr("channels", "chlist", chlist)
    header += _attr("compression", "compression", bytes([comp]))
    header += _attr("dataWindow", "box2i", box)
    header += _attr("displayWindow", "box2i", box)
    header += _attr("lineOrder", "lineOrder", b"\0")
    header += _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    header += _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
    header += _attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
    header += b"\0"
    lpb = _LINES_PER_BLOCK[comp]
    nblocks = (h + lpb - 1) // lpb
    stacked = np.stack(arrays, axis=1)  # (H, C, W): per scanline, channel after channel
    chunks = []
    for bi in range(nblocks):
        y0 = bi * lpb
        raw = stacked[y0 : y0 + lpb].tobytes()
        data = raw
        if comp != 0:
            enc = _pxr24_encode(stacked[y0 : y0 + lpb]) if comp == 5 else _zip_encode(raw)
            if len(enc) < len(raw):
                data = enc
        chunks.append(struct.pack("<ii", y0, len(data)) + data)
    offsets, pos = [], len(header) + 8 * nblocks
    for c in chunks:
        offsets.append(pos)
        pos += len(c)
    Path(path).write_bytes(header + struct.pack(f"<{nblocks}Q", *offsets) + b"".join(chunks))


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Reads a scanline EXR with float32 channels (none / ZIPS / ZIP / PXR24)."""
    data = Path(path).read_bytes()
    magic, version = struct.unpack("<ii", data[:8])
    if magic != _EXR_MAGIC or (version & 0xFF) != 2 or version & 0x200:
        raise ValueError(f"{path}: not a single-part scanline EXR")
    pos, attrs = 8, {}
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        tend = data.index(b"\0", end + 1)
        typ = data[end + 1 : tend].decode()
        (size,) = struct.unpack("<i", data[tend + 1 : tend + 5])
        attrs[name] = (typ, data[tend + 5 : tend + 5 + size])
        pos = tend + 5 + size
    pos += 1
    ch, names = attrs["channels"][1], []
    p = 0
    while ch[p] != 0:
        e = ch.index(b"\0", p)
        (ptype,) = struct.unpack("<i", ch[e + 1 : e + 5])
        if ptype != _EXR_FLOAT:
            raise ValueError(f"{path}: only float32 channels are supported")
        names.append(ch[p:e].decode())
        p = e + 17
    comp = attrs["compression"][1][0]
    if comp not in _LINES_PER_BLOCK:
        raise ValueError(f"{path}: unsupported EXR compression {comp}")
    x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"][1])
    w, h = x1 - x0 + 1, y1 - y0 + 1
    lpb = _LINES_PER_BLOCK[comp]
    nblocks = (h + lpb - 1) // lpb
    offsets = struct.unpack(f"<{nblocks}Q", data[pos : pos + 8 * nblocks])
    out = np.zeros((h, len(names), w), np.float32)
    for off in offsets:
        yb, size = struct.unpack("<ii", data[off : off + 8])
        nl = min(lpb, y1 + 1 - yb)
        want = nl * len(names) * w * 4
        blk = data[off + 8 : off + 8 + size]
        if size == want:
            vals = np.frombuffer(blk, "<f4").reshape(nl, len(names), w)
        elif comp == 5:
            vals = _pxr24_decode(blk, nl, len(names), w)
        else:
            vals = np.frombuffer(_zip_decode(blk, want), "<f4").reshape(nl, len(names), w)
        out[yb - y0 : yb - y0 + nl] = vals
    return {n: out[:, i, :].copy() for i, n in enumerate(names)}
