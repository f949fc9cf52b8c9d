"""Procedural meshes, textures and camera layouts for the synthetic scenes.

Everything is generated here from a few parameters (no downloaded assets). World
space is right-handed with +z up (as in Blender / NeRF-synthetic).

A `Mesh` carries triangles, optional per-vertex normals (smooth shading) and optional
UVs. Meshes without normals are rendered with face normals (flat shading), so their
shading normal is exactly the geometric normal: faces meet at sharp creases.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# --------------------------------------------------------------------------- meshes


@dataclass
class Mesh:
    V: np.ndarray  # (n, 3) float64 positions
    F: np.ndarray  # (m, 3) int32 triangles, counter-clockwise seen from outside
    N: np.ndarray | None = None  # (n, 3) unit normals (smooth); None = flat shading
    UV: np.ndarray | None = None  # (n, 2) texture coordinates

    def transformed(self, M: np.ndarray) -> "Mesh":
        """Applies a 4x4 affine transform (normals use the inverse transpose)."""
        M = np.asarray(M, float)
        V = self.V @ M[:3, :3].T + M[:3, 3]
        N = None
        if self.N is not None:
            N = self.N @ np.linalg.inv(M[:3, :3])
            N /= np.linalg.norm(N, axis=1, keepdims=True)
        F = self.F if np.linalg.det(M[:3, :3]) > 0 else self.F[:, ::-1].copy()
        return Mesh(V, F, N, self.UV)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.V.min(axis=0), self.V.max(axis=0)


def merge(meshes: list[Mesh]) -> Mesh:
    """Concatenates meshes that are all flat or all smooth (UVs are kept if all have them)."""
    vs, fs, ns, uvs, off = [], [], [], [], 0
    smooth = meshes[0].N is not None
    has_uv = all(m.UV is not None for m in meshes)
    for m in meshes:
        if (m.N is not None) != smooth:
            raise ValueError("merge: mixing flat and smooth meshes")
        vs.append(m.V)
        fs.append(m.F + off)
        off += len(m.V)
        if smooth:
            ns.append(m.N)
        if has_uv:
            uvs.append(m.UV)
    return Mesh(
        np.concatenate(vs),
        np.concatenate(fs).astype(np.int32),
        np.concatenate(ns) if smooth else None,
        np.concatenate(uvs) if has_uv else None,
    )


def write_ply(path: str | Path, mesh: Mesh, compact: bool = False) -> None:
    """Binary little-endian PLY with x y z [nx ny nz] [u v] and uchar/int faces
    (`compact`: uchar/ushort faces when the indices fit, for committed files)."""
    n, m = len(mesh.V), len(mesh.F)
    cols = [mesh.V]
    props = ["x", "y", "z"]
    if mesh.N is not None:
        cols.append(mesh.N)
        props += ["nx", "ny", "nz"]
    if mesh.UV is not None:
        cols.append(mesh.UV)
        props += ["u", "v"]
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    head += [f"property float {p}" for p in props]
    short = compact and n <= 65536
    head += [f"element face {m}", f"property list uchar {'ushort' if short else 'int'} vertex_indices", "end_header"]
    vdata = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4").tobytes()
    fdt = np.dtype([("n", "u1"), ("i", "<u2" if short else "<i4", (3,))])
    faces = np.zeros(m, fdt)
    faces["n"] = 3
    faces["i"] = mesh.F
    Path(path).write_bytes(("\n".join(head) + "\n").encode() + vdata + faces.tobytes())


def icosphere(center, radius: float, subdiv: int = 3) -> Mesh:
    """Sphere as an icosahedron subdivided `subdiv` times (20 * 4^subdiv triangles),
    vertices on the sphere: the mesh of an analytic sphere in the ground-truth mesh.
    Its chords stay within radius * (1 - cos(edge / 2)) of the sphere (0.24 % of the
    radius at subdiv 3, 1280 triangles)."""
    t = (1 + math.sqrt(5)) / 2
    V = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    V = [np.array(v, float) / np.linalg.norm(v) for v in V]
    for _ in range(subdiv):
        mid: dict = {}

        def m(a, b):
            k = (min(a, b), max(a, b))
            if k not in mid:
                p = V[a] + V[b]
                V.append(p / np.linalg.norm(p))
                mid[k] = len(V) - 1
            return mid[k]

        F = [f for a, b, c in F for f in ((a, m(a, b), m(c, a)), (b, m(b, c), m(a, b)), (c, m(c, a), m(b, c)),
                                           (m(a, b), m(b, c), m(c, a)))]
    return Mesh(np.asarray(center, float) + radius * np.array(V), np.array(F, np.int32))


def merge_surfaces(meshes: list[Mesh]) -> Mesh:
    """Concatenates positions and triangles only (no normals or UVs): the shapes of a
    scene as one surface."""
    return merge([Mesh(m.V, m.F) for m in meshes])


def translate(t) -> np.ndarray:
    M = np.eye(4)
    M[:3, 3] = t
    return M


def scale(s) -> np.ndarray:
    return np.diag(list(np.broadcast_to(np.asarray(s, float), (3,))) + [1.0])


def rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    return M


def rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    M = np.eye(4)
    M[1:3, 1:3] = [[c, -s], [s, c]]
    return M


def rot_y(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    M = np.eye(4)
    M[0, 0], M[0, 2], M[2, 0], M[2, 2] = c, s, -s, c
    return M


def chain(*Ms: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    for M in Ms:
        out = out @ M
    return out


def quad(p0, p1, p2, p3, uv_scale=(1.0, 1.0)) -> Mesh:
    """Flat quad p0-p1-p2-p3 (counter-clockwise seen from the front) with UVs 0..1."""
    V = np.array([p0, p1, p2, p3], float)
    su, sv = uv_scale
    UV = np.array([[0, 0], [su, 0], [su, sv], [0, sv]], float)
    return Mesh(V, np.array([[0, 1, 2], [0, 2, 3]], np.int32), None, UV)


def box(lo, hi) -> Mesh:
    """Axis-aligned box with its own 4 vertices per face (flat), UVs 0..1 per face."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    faces = [
        quad((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)),  # -z
        quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)),  # +z
        quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)),  # -y
        quad((x1, y1, z0), (x0, y1, z0), (x0, y1, z1), (x1, y1, z1)),  # +y
        quad((x0, y1, z0), (x0, y0, z0), (x0, y0, z1), (x0, y1, z1)),  # -x
        quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)),  # +x
    ]
    return merge(faces)


def prism(profile: list[tuple[float, float]], length: float) -> Mesh:
    """Extrudes a convex 2D profile (x, z), counter-clockwise, along y in [0, length]."""
    P = np.array(profile, float)
    k = len(P)
    parts = []
    for i in range(k):
        a, b = P[i], P[(i + 1) % k]
        parts.append(
            quad((a[0], length, a[1]), (b[0], length, b[1]), (b[0], 0.0, b[1]), (a[0], 0.0, a[1]))
        )
    # caps (fan triangulation of the convex profile)
    for y, flip in ((0.0, False), (length, True)):
        V = np.array([[p[0], y, p[1]] for p in P])
        F = np.array([[0, i, i + 1] for i in range(1, k - 1)], np.int32)
        if flip:
            F = F[:, ::-1].copy()
        UV = (P - P.min(0)) / np.maximum(np.ptp(P, 0), 1e-9)
        parts.append(Mesh(V, F, None, UV))
    return merge(parts)


def stairs(n: int, width: float, tread: float, rise: float) -> Mesh:
    """A staircase of `n` steps: columns x in [k*tread, (k+1)*tread], z in [0, (k+1)*rise]."""
    return merge([box((k * tread, 0.0, 0.0), ((k + 1) * tread, width, (k + 1) * rise)) for k in range(n)])


def pyramid(base: float, height: float) -> Mesh:
    """Square pyramid, base centred at the origin on z = 0."""
    h = base / 2
    c = [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)]
    apex = (0, 0, height)
    parts = [quad(c[0], c[3], c[2], c[1])]
    for i in range(4):
        a, b = c[i], c[(i + 1) % 4]
        parts.append(Mesh(np.array([a, b, apex], float), np.array([[0, 1, 2]], np.int32), None,
                          np.array([[0, 0], [1, 0], [0.5, 1]], float)))
    return merge(parts)


def _grid_faces(nu: int, nv: int, wrap_u: bool, wrap_v: bool) -> np.ndarray:
    """Triangles of an (nu x nv) vertex grid, index = i * nv + j."""
    F = []
    iu = nu if wrap_u else nu - 1
    iv = nv if wrap_v else nv - 1
    for i in range(iu):
        for j in range(iv):
            a = i * nv + j
            b = ((i + 1) % nu) * nv + j
            c = ((i + 1) % nu) * nv + (j + 1) % nv
            d = i * nv + (j + 1) % nv
            F.append((a, b, c))
            F.append((a, c, d))
    return np.array(F, np.int32)


def torus(R: float, r: float, nu: int = 96, nv: int = 48, arc_deg: float = 360.0) -> Mesh:
    """Torus around the z axis, smooth analytic normals. `arc_deg` < 360 gives an open
    piece of the ring, symmetric about +x."""
    full = arc_deg >= 360.0
    a = math.radians(arc_deg)
    u = np.linspace(0, 2 * np.pi, nu, endpoint=False) if full else np.linspace(-a / 2, a / 2, nu)
    v = np.linspace(0, 2 * np.pi, nv, endpoint=False)
    U, Vv = np.meshgrid(u, v, indexing="ij")
    N = np.stack([np.cos(Vv) * np.cos(U), np.cos(Vv) * np.sin(U), np.sin(Vv)], -1).reshape(-1, 3)
    C = np.stack([R * np.cos(U), R * np.sin(U), 0 * U], -1).reshape(-1, 3)
    P = C + r * N
    return Mesh(P, _grid_faces(nu, nv, full, True), N)


def lathe(profile: list[tuple[float, float]], n: int = 96, samples: int = 8, cap_top=False,
          cap_bottom=False, sharp: bool = False) -> Mesh:
    """Surface of revolution about z of a profile [(radius, z), ...].

    `sharp=False`: the profile is resampled with a Catmull-Rom spline (`samples` per
    segment) and shaded smooth, normals from the spline tangent. `sharp=True`: the
    profile is piecewise linear, each segment its own band of vertices with the
    segment's normal (cylinders, cones and discs, creased where segments meet).
    Normals point to the right of the profile direction (outward for a profile that
    goes up the outside). UVs: u around the axis, v along the profile (arc length)."""
    P = np.array(profile, float)
    if sharp:
        bands = [_lathe_band(np.array([P[i], P[i + 1]]), n, None) for i in range(len(P) - 1)]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
        for i, b in enumerate(bands):
            b.UV[:, 1] = np.where(b.UV[:, 1] > 0.5, arc[i + 1], arc[i]) / arc[-1]
        parts = bands
        Q = P
    else:
        pts = [P[0]]
        for i in range(len(P) - 1):
            p0 = P[max(i - 1, 0)]
            p1, p2 = P[i], P[i + 1]
            p3 = P[min(i + 2, len(P) - 1)]
            for s in range(1, samples + 1):
                t = s / samples
                pts.append(0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t * t
                                  + (-p0 + 3 * p1 - 3 * p2 + p3) * t ** 3))
        Q = np.array(pts)
        parts = [_lathe_band(Q, n, np.gradient(Q, axis=0))]
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    for cap, idx, nz in ((cap_bottom, 0, -1.0), (cap_top, len(Q) - 1, 1.0)):
        if not cap:
            continue
        r, z = Q[idx]
        Vc = np.concatenate([[[0, 0, z]], np.stack([r * np.cos(u), r * np.sin(u), np.full(n, z)], -1)])
        F = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)], np.int32)
        if nz < 0:
            F = F[:, ::-1].copy()
        UVc = np.full((n + 1, 2), 0.0 if nz < 0 else 1.0)
        UVc[:, 0] = 0.5
        parts.append(Mesh(Vc, F, np.tile([0.0, 0.0, nz], (n + 1, 1)), UVc))
    return merge(parts)


def _lathe_band(Q: np.ndarray, n: int, T: np.ndarray | None) -> Mesh:
    """Revolves the polyline Q (radius, z); normals from tangents T (None: the single
    segment's own direction)."""
    if T is None:
        T = np.repeat(Q[1:2] - Q[0:1], len(Q), axis=0)
    N2 = np.stack([T[:, 1], -T[:, 0]], -1)
    N2 /= np.linalg.norm(N2, axis=1, keepdims=True)
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    cu, su = np.cos(u)[:, None], np.sin(u)[:, None]
    V = np.stack([Q[None, :, 0] * cu, Q[None, :, 0] * su, np.broadcast_to(Q[None, :, 1], (n, len(Q)))], -1)
    N = np.stack([N2[None, :, 0] * cu, N2[None, :, 0] * su, np.broadcast_to(N2[None, :, 1], (n, len(Q)))], -1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))])
    Uu, Vv = np.meshgrid(np.arange(n) / n, arc / max(arc[-1], 1e-12), indexing="ij")
    UV = np.stack([Uu, Vv], -1).reshape(-1, 2)
    return Mesh(V.reshape(-1, 3), _grid_faces(n, len(Q), True, False), N.reshape(-1, 3), UV)


def cylinder(radius: float, z0: float, z1: float, n: int = 48, caps: bool = True) -> Mesh:
    """Cylinder about z, smooth side, flat caps (caps have their own vertices)."""
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(u), np.sin(u), 0 * u], -1)
    V = np.concatenate([radius * ring + [0, 0, z0], radius * ring + [0, 0, z1]])
    N = np.concatenate([ring, ring])
    F = []
    for i in range(n):
        j = (i + 1) % n
        F += [(i, j, n + j), (i, n + j, n + i)]
    parts = [Mesh(V, np.array(F, np.int32), N)]
    if caps:
        for z, nz in ((z0, -1.0), (z1, 1.0)):
            Vc = np.concatenate([[[0, 0, z]], radius * ring + [0, 0, z]])
            Fc = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)], np.int32)
            if nz < 0:
                Fc = Fc[:, ::-1].copy()
            parts.append(Mesh(Vc, Fc, np.tile([0.0, 0.0, nz], (n + 1, 1))))
    return merge(parts)


def rod(p0, p1, radius: float, n: int = 16) -> Mesh:
    """Capped cylinder from p0 to p1 (smooth sides)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    L = np.linalg.norm(d)
    z = d / L
    a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = x, y, z, p0
    return cylinder(radius, 0.0, L, n).transformed(M)


def heightfield(size: float, n: int, height_fn, grad_fn=None) -> Mesh:
    """Square heightfield z = h(x, y) over [-size/2, size/2]^2 with smooth normals from
    the gradient of h (`grad_fn`, or central differences of h with a tiny step)."""
    t = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(t, t, indexing="ij")
    Z = height_fn(X, Y)
    if grad_fn is None:
        e = 1e-6
        gx = (height_fn(X + e, Y) - height_fn(X - e, Y)) / (2 * e)
        gy = (height_fn(X, Y + e) - height_fn(X, Y - e)) / (2 * e)
    else:
        gx, gy = grad_fn(X, Y)
    N = np.stack([-gx, -gy, np.ones_like(Z)], -1)
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    V = np.stack([X, Y, Z], -1).reshape(-1, 3)
    UV = np.stack([(X + size / 2) / size, (Y + size / 2) / size], -1).reshape(-1, 2)
    return Mesh(V, _grid_faces(n, n, False, False), N.reshape(-1, 3), UV)


# --------------------------------------------------------------------------- textures
# Linear-RGB float32 arrays (H, W, 3); row 0 is the top of the image (v = 1): the
# renderer flips them for Mitsuba, whose bitmap row 0 is v = 0.


def checker(res: int, n: int, c0, c1) -> np.ndarray:
    i = (np.arange(res) * n // res)
    m = (i[:, None] + i[None, :]) % 2 == 0
    return np.where(m[..., None], np.array(c0, np.float32), np.array(c1, np.float32)).astype(np.float32)


def stripes(res: int, n: int, c0, c1, vertical: bool = True) -> np.ndarray:
    i = (np.arange(res) * n // res) % 2 == 0
    m = np.broadcast_to(i[None, :] if vertical else i[:, None], (res, res))
    return np.where(m[..., None], np.array(c0, np.float32), np.array(c1, np.float32)).astype(np.float32)


# A 5x7 block font for the few letters the posters use.
_FONT = {
    "E": ["11111", "10000", "10000", "11110", "10000", "10000", "11111"],
    "D": ["11110", "10001", "10001", "10001", "10001", "10001", "11110"],
    "G": ["01111", "10000", "10000", "10011", "10001", "10001", "01111"],
    "N": ["10001", "11001", "10101", "10011", "10001", "10001", "10001"],
    "R": ["11110", "10001", "10001", "11110", "10100", "10010", "10001"],
    "F": ["11111", "10000", "10000", "11110", "10000", "10000", "10000"],
    "S": ["01111", "10000", "10000", "01110", "00001", "00001", "11110"],
    "T": ["11111", "00100", "00100", "00100", "00100", "00100", "00100"],
    "A": ["01110", "10001", "10001", "11111", "10001", "10001", "10001"],
    "X": ["10001", "10001", "01010", "00100", "01010", "10001", "10001"],
    "3": ["11110", "00001", "00001", "01110", "00001", "00001", "11110"],
    " ": ["00000"] * 7,
}


def text_mask(text: str, cell: int) -> np.ndarray:
    """Boolean raster of `text` in the block font, `cell` texels per font pixel."""
    rows = []
    for r in range(7):
        row = []
        for ch in text:
            row += [c == "1" for c in _FONT[ch][r]] + [False]
        rows.append(row[:-1])
    m = np.array(rows, bool)
    return np.kron(m, np.ones((cell, cell), bool))


def paste(img: np.ndarray, mask: np.ndarray, top: int, left: int, color) -> None:
    h, w = mask.shape
    region = img[top : top + h, left : left + w]
    region[mask[: region.shape[0], : region.shape[1]]] = color


# --------------------------------------------------------------------------- cameras


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """NeRF / OpenGL camera-to-world: columns right, up, back (camera looks down -z), eye."""
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = r, u, -f, eye
    return M


def fibonacci_hemisphere(n: int, elev_min: float, elev_max: float, phase: float = 0.0) -> np.ndarray:
    """`n` unit directions spread evenly (golden-angle spiral) over the band of
    elevations [elev_min, elev_max] degrees of the upper hemisphere."""
    zmin, zmax = math.sin(math.radians(elev_min)), math.sin(math.radians(elev_max))
    golden = math.pi * (3 - math.sqrt(5))
    out = []
    for i in range(n):
        z = zmin + (zmax - zmin) * (i + 0.5) / n
        r = math.sqrt(max(0.0, 1 - z * z))
        a = i * golden + phase
        out.append((r * math.cos(a), r * math.sin(a), z))
    return np.array(out)


def ring(n: int, elev: float, phase: float = 0.0) -> np.ndarray:
    e = math.radians(elev)
    a = phase + np.arange(n) * 2 * math.pi / n
    return np.stack([math.cos(e) * np.cos(a), math.cos(e) * np.sin(a), np.full(n, math.sin(e))], -1)
