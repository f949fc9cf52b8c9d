"""The eight synthetic scenes: geometry, materials, lighting and camera layouts.

Each scene is a purposeful test of one thing a sparse-view NeRF with edge-guided
depth / normal regularisation must get right. World space is +z up, units are
arbitrary ("metres"). Every shape lies inside the scene's `aabb` (checked at render
time), and every ground-truth depth lies inside [near, far] (also checked).

Layouts:
* ``forward``   - LLFF-like: camera centres on a small plane in front of the scene,
                  all looking roughly the same way (slight convergence on a target).
* ``object``    - object-centric: cameras on a band of the upper hemisphere around
                  the scene, looking at its centre (DTU / NeRF-synthetic-like).
* ``turntable`` - Blender / NeRF-synthetic-like: training cameras at random on the
                  upper hemisphere, test cameras on a ring (a turntable path).
* ``inward``    - inside-out: cameras stand inside a room on a horizontal circle
                  around its centre and look inward, each seeing the opposite walls;
                  training views on an arc of 240 deg (so any three evenly picked views
                  are ~120 deg apart), test views spread over the full circle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

import geometry as g


@dataclass
class Shape:
    name: str
    mesh: g.Mesh | None = None
    sphere: tuple[tuple[float, float, float], float] | None = None  # analytic sphere
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)  # linear albedo
    texture: np.ndarray | None = None  # linear albedo texture (H, W, 3)


@dataclass
class SceneSpec:
    name: str
    description: str
    layout: str  # "forward" | "object" | "turntable" | "inward"
    aabb: tuple[tuple[float, float, float], tuple[float, float, float]]
    near: float
    far: float
    fov_x: float  # degrees
    aspect: float  # width / height
    background: str  # "geometry" (walls fill every pixel) | "transparent" (RGBA)
    build: Callable[[], list[Shape]]
    cameras: Callable[[int, int], tuple[list[np.ndarray], list[np.ndarray]]]
    sun_dir: tuple[float, float, float] = (0.45, 0.35, -0.82)  # direction light travels
    sun_irradiance: float = 2.4
    sky: tuple[float, float, float] = (0.32, 0.36, 0.42)
    extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- cameras


def _halton(i: int, base: int) -> float:
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def forward_cameras(center, half_extent, target, up=(0.0, 0.0, 1.0)):
    """LLFF-like layout: camera centres spread (Halton points) over a rectangle of
    half-size `half_extent` = (right, up) around `center`, on the plane facing
    `target`; every camera looks at `target`. Test views are interleaved with the
    training views: of all n_train + n_test Halton points, every k-th is a test view."""
    center = np.asarray(center, float)
    fwd = np.asarray(target, float) - center
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)

    def make(n_train: int, n_test: int):
        total = n_train + n_test
        test_idx = set(np.round(np.linspace(0, total - 1, n_test) + 0.5 * total / max(n_test, 1) - 0.5)
                       .astype(int).clip(0, total - 1).tolist()) if n_test else set()
        while len(test_idx) < n_test:  # collisions (tiny totals): fill deterministically
            test_idx.add(min(set(range(total)) - test_idx))
        train, test = [], []
        for i in range(total):
            a, b = _halton(i + 1, 2) * 2 - 1, _halton(i + 1, 3) * 2 - 1
            eye = center + a * half_extent[0] * right + b * half_extent[1] * upv
            (test if i in test_idx else train).append(g.look_at(eye, target, up))
        return train, test

    return make


def object_cameras(radius, target, elev_min, elev_max):
    """Object-centric layout: camera directions on a golden-angle spiral over the
    elevation band [elev_min, elev_max] (degrees); test views use a second spiral,
    rotated by half the golden angle, so they fall between the training views."""
    target = np.asarray(target, float)

    def make(n_train: int, n_test: int):
        golden = math.pi * (3 - math.sqrt(5))
        tr = g.fibonacci_hemisphere(n_train, elev_min, elev_max, 0.0)
        te = g.fibonacci_hemisphere(n_test, elev_min + 2.0, elev_max - 2.0, golden / 2 + 1.0)
        return ([g.look_at(target + radius * d, target) for d in tr],
                [g.look_at(target + radius * d, target) for d in te])

    return make


def turntable_cameras(radius, target, elev_min, elev_max, test_elev, seed):
    """Blender-like layout: training cameras at seeded-random directions on the upper
    hemisphere band, test cameras evenly spaced on a ring at `test_elev` degrees."""
    target = np.asarray(target, float)

    def make(n_train: int, n_test: int):
        rng = np.random.default_rng(seed)
        zmin, zmax = math.sin(math.radians(elev_min)), math.sin(math.radians(elev_max))
        z = rng.uniform(zmin, zmax, n_train)
        a = rng.uniform(0, 2 * math.pi, n_train)
        r = np.sqrt(1 - z * z)
        tr = np.stack([r * np.cos(a), r * np.sin(a), z], -1)
        te = g.ring(n_test, test_elev, phase=0.3)
        return ([g.look_at(target + radius * d, target) for d in tr],
                [g.look_at(target + radius * d, target) for d in te])

    return make


def inward_cameras(radius, height, height_var, target, arc_deg=240.0, test_phase_deg=0.0):
    """Inside-out layout: camera centres on a horizontal circle of `radius` around the
    point under `target`, at heights `height` +- `height_var` (a fixed wobble, so no two
    views share a height), every camera looking at `target`. Training camera i sits at
    azimuth arc_deg * i / (n_train - 1) (counter-clockwise from +x): with the default
    240 deg, the views at round(linspace(0, n_train - 1, 3)) are ~120 deg apart and face
    three different parts of the room. Test cameras are evenly spaced over the full
    circle, at azimuths 360 * (j + 0.5) / n_test + test_phase_deg: between the training
    views on the arc, and in the 120 deg gap the training views leave."""
    target = np.asarray(target, float)

    def eye(az_deg: float, k: float) -> np.ndarray:
        a = math.radians(az_deg)
        z = height + height_var * math.sin(2.3 * k + 0.4)
        return np.array([target[0] + radius * math.cos(a), target[1] + radius * math.sin(a), z])

    def make(n_train: int, n_test: int):
        tr = [eye(arc_deg * i / max(n_train - 1, 1), i) for i in range(n_train)]
        te = [eye(360.0 * (j + 0.5) / n_test + test_phase_deg, j + 0.5) for j in range(n_test)]
        return [g.look_at(e, target) for e in tr], [g.look_at(e, target) for e in te]

    return make


# --------------------------------------------------------------------------- helpers


def _plate(half: float = 1.25, thick: float = 0.06, color=(0.55, 0.55, 0.53)) -> Shape:
    return Shape("ground", g.box((-half, -half, -thick), (half, half, 0.0)), color=color)


def _room(x_half: float, y_front: float, y_wall: float, height: float, wall_color, floor_color,
          wall_tex=None, floor_tex=None, floor_uv=(1.0, 1.0), wall_uv=(1.0, 1.0)) -> list[Shape]:
    """A floor (z = 0) from y_front to y_wall and a back wall at y = y_wall."""
    floor = g.quad((-x_half, y_front, 0), (x_half, y_front, 0), (x_half, y_wall, 0), (-x_half, y_wall, 0),
                   uv_scale=floor_uv)
    wall = g.quad((-x_half, y_wall, 0), (x_half, y_wall, 0), (x_half, y_wall, height), (-x_half, y_wall, height),
                  uv_scale=wall_uv)
    return [Shape("floor", floor, color=floor_color, texture=floor_tex),
            Shape("wall", wall, color=wall_color, texture=wall_tex)]


def _place(mesh: g.Mesh, *Ms) -> g.Mesh:
    return mesh.transformed(g.chain(*Ms))


# --------------------------------------------------------------------------- scenes


def build_occlusion() -> list[Shape]:
    s = _room(4.5, -2.0, 3.0, 4.2, wall_color=(0.62, 0.6, 0.56), floor_color=(0.42, 0.4, 0.37))
    s += [
        # a tall pillar far in front of the wall: large discontinuity
        Shape("pillar", g.box((-1.3, 0.05, 0.0), (-0.95, 0.4, 2.3)), color=(0.2, 0.33, 0.55)),
        # a slab hung 0.12 in front of the wall: small discontinuity
        Shape("slab", g.box((-0.6, 2.76, 1.1), (0.9, 2.88, 2.2)), color=(0.7, 0.55, 0.3)),
        # a panel on a post at mid depth, overlapping the slab in most views
        Shape("panel", g.box((-0.1, 1.55, 0.75), (1.1, 1.62, 1.45)), color=(0.65, 0.2, 0.18)),
        Shape("post", g.box((0.46, 1.56, 0.0), (0.54, 1.61, 0.75)), color=(0.3, 0.3, 0.3)),
        # a sphere in front of the panel, a cube in front of everything
        Shape("ball", sphere=((0.55, 0.45, 0.42), 0.42), color=(0.25, 0.55, 0.3)),
        Shape("cube", _place(g.box((-0.2, -0.2, 0.0), (0.2, 0.2, 0.4)), g.translate((-0.45, -0.35, 0.0)),
                             g.rot_z(30)), color=(0.85, 0.75, 0.35)),
        # a column behind the ball, and a low step near the wall
        Shape("column", g.cylinder(0.22, 0.0, 1.6, 64).transformed(g.translate((1.4, 1.1, 0.0))),
              color=(0.55, 0.5, 0.7)),
        Shape("step", g.box((-2.4, 2.1, 0.0), (-0.9, 3.0, 0.45)), color=(0.5, 0.45, 0.4)),
        # a thin plank leaning nowhere: floating shelf 0.3 from the wall
        Shape("shelf", g.box((-2.6, 2.55, 1.5), (-1.6, 2.7, 1.62)), color=(0.35, 0.25, 0.2)),
    ]
    return s


def build_creases() -> list[Shape]:
    prism = g.prism([(-0.3, 0.0), (0.3, 0.0), (0.0, 0.5)], 0.8)
    return [
        _plate(),
        Shape("box", _place(g.box((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6)), g.translate((-0.55, -0.5, 0.0)),
                            g.rot_z(25)), color=(0.75, 0.33, 0.22)),
        Shape("prism", _place(prism, g.translate((0.55, -0.45, 0.0)), g.rot_z(-20), g.translate((0, -0.4, 0))),
              color=(0.25, 0.48, 0.75)),
        Shape("stairs", _place(g.stairs(4, 0.6, 0.17, 0.15), g.translate((-0.75, 0.25, 0.0)), g.rot_z(10)),
              color=(0.85, 0.72, 0.38)),
        Shape("pyramid", _place(g.pyramid(0.55, 0.65), g.translate((0.6, 0.55, 0.0)), g.rot_z(15)),
              color=(0.38, 0.66, 0.38)),
        # an octahedron balanced on the plate: creases in every direction
        Shape("octahedron", _place(_octahedron(0.26), g.translate((0.05, 0.05, 0.26)), g.rot_z(10)),
              color=(0.72, 0.6, 0.78)),
    ]


def _octahedron(r: float) -> g.Mesh:
    V = np.array([[r, 0, 0], [-r, 0, 0], [0, r, 0], [0, -r, 0], [0, 0, r], [0, 0, -r]], float)
    F = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    parts = [g.Mesh(V[list(f)], np.array([[0, 1, 2]], np.int32)) for f in F]
    return g.merge(parts)


def _poster_texture() -> np.ndarray:
    res = 1024
    img = np.empty((res // 2, res, 3), np.float32)
    img[:] = (0.78, 0.75, 0.68)
    t = g.text_mask("EDGE NERF", 10)
    g.paste(img, t, 60, (res - t.shape[1]) // 2, (0.06, 0.06, 0.08))
    # a barcode band
    rng = np.random.default_rng(7)
    x = 80
    while x < res - 80:
        w = int(rng.integers(4, 22))
        if rng.random() < 0.5:
            img[200:300, x : x + w] = (0.05, 0.05, 0.05)
        x += w
    # red / white stripes at the bottom
    band = g.stripes(res, 24, (0.7, 0.08, 0.06), (0.85, 0.83, 0.78), vertical=True)[: 140]
    img[340:480] = band
    return img


def build_texture() -> list[Shape]:
    floor_tex = g.checker(512, 16, (0.08, 0.08, 0.08), (0.75, 0.75, 0.72))
    s = _room(4.5, -2.0, 3.0, 4.2, wall_color=(0.6, 0.6, 0.6), floor_color=(0.5, 0.5, 0.5),
              floor_tex=floor_tex)
    s.append(Shape("poster", g.quad((-1.8, 2.99, 0.9), (1.8, 2.99, 0.9), (1.8, 2.99, 2.7), (-1.8, 2.99, 2.7)),
                   texture=_poster_texture()))
    box_tex = g.stripes(512, 8, (0.1, 0.2, 0.55), (0.9, 0.85, 0.6), vertical=True)
    s.append(Shape("box", _place(g.box((-0.4, -0.4, 0.0), (0.4, 0.4, 0.8)), g.translate((-0.6, 1.1, 0.0)),
                                 g.rot_z(35)), texture=box_tex))
    # a free-standing flat board with letters and bars (texture on a plane, seen obliquely)
    board_tex = np.empty((512, 512, 3), np.float32)
    board_tex[:] = (0.9, 0.9, 0.86)
    t = g.text_mask("TEXT", 18)
    g.paste(board_tex, t, 60, (512 - t.shape[1]) // 2, (0.55, 0.08, 0.1))
    for k in range(6):
        board_tex[260 + k * 40 : 260 + k * 40 + 18, 60:452] = (0.05, 0.3 + 0.1 * k, 0.15)
    board = g.quad((-0.55, 0, 0.0), (0.55, 0, 0.0), (0.55, 0, 1.1), (-0.55, 0, 1.1))
    s.append(Shape("board", _place(board, g.translate((0.95, 0.6, 0.0)), g.rot_z(-25)), texture=board_tex))
    return s


def build_thin() -> list[Shape]:
    s = [_plate(color=(0.6, 0.58, 0.55))]
    # a picket fence along the back edge: pickets and two rails
    pick = []
    for k in range(11):
        x = -1.0 + 0.2 * k
        pick.append(g.box((x - 0.022, -0.86, 0.0), (x + 0.022, -0.82, 0.75)))
    rails = [g.box((-1.05, -0.9, z - 0.02), (1.05, -0.86, z + 0.02)) for z in (0.2, 0.55)]
    s.append(Shape("fence", g.merge(pick + rails), color=(0.85, 0.85, 0.8)))
    # a row of vertical rods of decreasing radius
    rods = [g.rod((-0.9 + 0.22 * k, 0.05, 0.0), (-0.9 + 0.22 * k, 0.05, 0.95), r, 24)
            for k, r in enumerate((0.045, 0.03, 0.02, 0.014, 0.01))]
    s.append(Shape("rods", g.merge(rods), color=(0.75, 0.3, 0.2)))
    # a wire-frame cube
    c = np.array([[x, y, z] for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.0, 0.6)])
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]
    M = g.chain(g.translate((0.55, 0.45, 0.02)), g.rot_z(20))
    cw = (c @ M[:3, :3].T) + M[:3, 3]
    s.append(Shape("wirecube", g.merge([g.rod(cw[i], cw[j], 0.018, 12) for i, j in edges]),
                   color=(0.2, 0.35, 0.7)))
    # a tall antenna: thin mast with cross-bars
    parts = [g.rod((-0.35, 0.75, 0.0), (-0.35, 0.75, 1.2), 0.015, 12)]
    for k, z in enumerate((0.5, 0.75, 1.0)):
        w = 0.35 - 0.08 * k
        parts.append(g.rod((-0.35 - w, 0.75, z), (-0.35 + w, 0.75, z), 0.01, 12))
    s.append(Shape("antenna", g.merge(parts), color=(0.25, 0.25, 0.25)))
    return s


def _mound(X, Y, size=1.2):
    """A bumpy mound that meets the plate with zero height and slope at its border."""
    u, v = X / size + 0.5, Y / size + 0.5
    win = (np.sin(np.pi * np.clip(u, 0, 1)) * np.sin(np.pi * np.clip(v, 0, 1))) ** 2
    bumps = 0.2 + 0.08 * np.sin(7.5 * X + 0.5) * np.cos(6.5 * Y) + 0.04 * np.cos(11.0 * X - 5.0 * Y)
    return win * bumps


def build_smooth() -> list[Shape]:
    # lifted 3 mm so that its rim never z-fights with the plate
    mound = g.heightfield(1.2, 121, _mound).transformed(g.translate((-0.45, 0.45, 0.003)))
    egg = g.lathe([(0.0, 0.0), (0.16, 0.03), (0.24, 0.14), (0.25, 0.3), (0.2, 0.48), (0.1, 0.58), (0.0, 0.6)],
                  n=96, samples=10)
    return [
        _plate(color=(0.55, 0.53, 0.5)),
        Shape("mound", mound, color=(0.62, 0.55, 0.42)),
        Shape("sphere", sphere=((0.45, -0.4, 0.42), 0.42), color=(0.3, 0.45, 0.78)),
        Shape("torus", _place(g.torus(0.34, 0.12, 128, 64), g.translate((0.55, 0.58, 0.44)),
                              g.rot_z(-35), g.rot_x(75)), color=(0.8, 0.3, 0.35)),
        Shape("egg", egg.transformed(g.translate((-0.55, -0.55, -0.005))), color=(0.88, 0.82, 0.68)),
    ]


def _mug(x, y, z, r, hgt, color, name, angle=0.0) -> list[Shape]:
    # a cup as a solid of revolution with a thick rim and an inside; handle: half torus
    t = 0.012
    body = g.lathe([(0.0, 0.0), (r, 0.0), (r, hgt), (r - t, hgt), (r - t, 0.02), (0.0, 0.02)], n=64, sharp=True)
    handle = _place(g.torus(hgt * 0.28, 0.011, 32, 16, arc_deg=190), g.translate((r, 0, hgt * 0.5)), g.rot_x(90))
    M = g.chain(g.translate((x, y, z)), g.rot_z(angle))
    return [Shape(name, body.transformed(M), color=color), Shape(name + "_handle", handle.transformed(M), color=color)]


def build_table() -> list[Shape]:
    wood = g.stripes(256, 24, (0.45, 0.3, 0.18), (0.5, 0.34, 0.2), vertical=False)
    s = _room(4.0, -1.2, 2.4, 3.2, wall_color=(0.66, 0.64, 0.6), floor_color=(0.35, 0.33, 0.3))
    top = 0.76
    s.append(Shape("tabletop", g.box((-1.3, -0.7, top - 0.05), (1.3, 1.0, top)), texture=wood))
    legs = [g.box((x - 0.04, y - 0.04, 0.0), (x + 0.04, y + 0.04, top - 0.05))
            for x in (-1.2, 1.2) for y in (-0.6, 0.9)]
    s.append(Shape("legs", g.merge(legs), color=(0.3, 0.2, 0.12)))
    # books: a stack of three boxes and one standing
    books = [((-0.95, 0.45), (0.42, 0.3, 0.06), 8, (0.6, 0.15, 0.12)),
             ((-0.94, 0.46), (0.38, 0.27, 0.05), -4, (0.15, 0.3, 0.55)),
             ((-0.96, 0.44), (0.36, 0.26, 0.07), 3, (0.75, 0.65, 0.2))]
    z = top
    for i, ((x, y), (w, d, hh), ang, col) in enumerate(books):
        s.append(Shape(f"book{i}", _place(g.box((-w / 2, -d / 2, 0.0), (w / 2, d / 2, hh)),
                                          g.translate((x, y, z)), g.rot_z(ang)), color=col))
        z += hh
    s.append(Shape("book_upright", _place(g.box((-0.03, -0.14, 0.0), (0.03, 0.14, 0.38)),
                                          g.translate((-0.55, 0.75, top)), g.rot_z(-5)), color=(0.2, 0.5, 0.35)))
    s += _mug(-0.35, 0.05, top, 0.08, 0.17, (0.85, 0.85, 0.82), "mug", angle=200)
    s += _mug(0.95, 0.55, top, 0.07, 0.14, (0.2, 0.45, 0.7), "cup", angle=150)
    bowl = g.lathe([(0.0, 0.0), (0.12, 0.0), (0.2, 0.06), (0.24, 0.13), (0.225, 0.13), (0.185, 0.07),
                    (0.11, 0.02), (0.0, 0.02)], n=96, samples=4)
    s.append(Shape("bowl", bowl.transformed(g.translate((0.25, 0.45, top))), color=(0.75, 0.4, 0.2)))
    s.append(Shape("orange", sphere=((0.22, 0.42, top + 0.02 + 0.08), 0.08), color=(0.85, 0.42, 0.06)))
    s.append(Shape("apple", sphere=((0.5, -0.05, top + 0.075), 0.075), color=(0.6, 0.07, 0.06)))
    bottle = g.lathe([(0.0, 0.0), (0.07, 0.0), (0.075, 0.02), (0.075, 0.24), (0.05, 0.3), (0.025, 0.33),
                      (0.025, 0.42), (0.0, 0.42)], n=64, samples=4)
    s.append(Shape("bottle", bottle.transformed(g.translate((0.7, 0.7, top))), color=(0.12, 0.35, 0.18)))
    s.append(Shape("plate", g.cylinder(0.17, top, top + 0.015, 64).transformed(g.translate((-0.1, -0.35, 0.0))),
                   color=(0.9, 0.9, 0.88)))
    s.append(Shape("box", _place(g.box((-0.12, -0.08, 0.0), (0.12, 0.08, 0.14)), g.translate((0.95, -0.3, top)),
                                 g.rot_z(-25)), color=(0.55, 0.6, 0.8)))
    s.append(Shape("chair", g.merge([g.box((-0.3, 1.2, 0.45), (0.3, 1.7, 0.5)),
                                     g.box((-0.3, 1.65, 0.5), (0.3, 1.7, 1.1))] +
                                    [g.box((x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.45))
                                     for x in (-0.26, 0.26) for y in (1.24, 1.66)]),
                   color=(0.4, 0.28, 0.18)))
    return s


def build_turntable() -> list[Shape]:
    s = []
    octa = g.prism([(0.55 * math.cos(a), 0.55 * math.sin(a)) for a in np.arange(8) * math.pi / 4 + math.pi / 8],
                   0.18)
    s.append(Shape("base", octa.transformed(g.rot_x(90)), color=(0.45, 0.45, 0.47)))
    bands = g.stripes(256, 8, (0.78, 0.12, 0.1), (0.9, 0.9, 0.88), vertical=False)
    prof = [(0.36, 0.18), (0.33, 0.6), (0.29, 1.0), (0.26, 1.3)]
    tower = g.lathe(prof, n=96, samples=4)
    radius_at = lambda z: float(np.interp(z, [p[1] for p in prof], [p[0] for p in prof]))  # noqa: E731
    s.append(Shape("tower", tower, texture=bands))
    s.append(Shape("gallery", g.cylinder(0.38, 1.3, 1.34, 96), color=(0.2, 0.2, 0.22)))
    rail = [g.rod((0.36 * math.cos(a), 0.36 * math.sin(a), 1.34), (0.36 * math.cos(a), 0.36 * math.sin(a), 1.46),
                  0.008, 8) for a in np.arange(24) * 2 * math.pi / 24]
    s.append(Shape("railing", g.merge(rail + [g.torus(0.36, 0.01, 96, 8).transformed(g.translate((0, 0, 1.46)))]),
                   color=(0.15, 0.15, 0.15)))
    s.append(Shape("lantern", g.cylinder(0.19, 1.34, 1.56, 64), color=(0.85, 0.8, 0.45)))
    s.append(Shape("roof", g.lathe([(0.25, 1.56), (0.0, 1.8)], n=64, sharp=True, cap_bottom=True),
                   color=(0.7, 0.12, 0.1)))
    s.append(Shape("door", _place(g.box((-0.06, -0.03, 0.0), (0.06, 0.03, 0.22)), g.translate((0.0, -0.34, 0.18)),
                                  g.rot_x(-4)), color=(0.25, 0.15, 0.1)))
    win = [_place(g.box((-0.035, -0.025, 0.0), (0.035, 0.025, 0.09)),
                  g.rot_z(a), g.translate((0.0, -radius_at(z + 0.045) - 0.004, z)))
           for a, z in ((0, 0.62), (120, 0.8), (240, 0.98))]
    s.append(Shape("windows", g.merge(win), color=(0.1, 0.12, 0.18)))
    return s


def build_room() -> list[Shape]:
    # the inside of a 4 x 4 m room, walls 2.4 m high, no ceiling: sun and sky come in from above
    L, H = 2.0, 2.4
    planks = g.stripes(256, 24, (0.46, 0.33, 0.21), (0.52, 0.38, 0.24), vertical=True)
    s = [Shape("floor", g.quad((-L, -L, 0), (L, -L, 0), (L, L, 0), (-L, L, 0)), texture=planks)]
    # one plain colour per wall (quads facing inward)
    for name, p0, p1, col in (("wall_north", (L, L), (-L, L), (0.55, 0.6, 0.7)),
                              ("wall_west", (-L, L), (-L, -L), (0.74, 0.5, 0.44)),
                              ("wall_south", (-L, -L), (L, -L), (0.75, 0.67, 0.52)),
                              ("wall_east", (L, -L), (L, L), (0.52, 0.62, 0.45))):
        s.append(Shape(name, g.quad((*p0, 0), (*p1, 0), (*p1, H), (*p0, H)), color=col))
    # a poster on the north wall, 1 cm in front of it, hung low: the cameras look down at the
    # room's centre and see the walls only up to 1.05-1.2 m
    s.append(Shape("poster", g.quad((-1.1, 1.99, 0.3), (0.3, 1.99, 0.3), (0.3, 1.99, 1.0), (-1.1, 1.99, 1.0)),
                   texture=_poster_texture()))
    # a low sofa of boxes along the west wall: base, back, arms, two cushions with a 2 cm gap
    sofa = [g.box((-1.95, -0.9, 0.0), (-1.35, 0.9, 0.22)), g.box((-1.97, -0.9, 0.22), (-1.8, 0.9, 0.8)),
            g.box((-1.97, -1.05, 0.0), (-1.35, -0.9, 0.55)), g.box((-1.97, 0.9, 0.0), (-1.35, 1.05, 0.55))]
    s.append(Shape("sofa", g.merge(sofa), color=(0.16, 0.36, 0.4)))
    s.append(Shape("cushions", g.merge([g.box((-1.8, -0.9, 0.22), (-1.38, -0.01, 0.36)),
                                        g.box((-1.8, 0.01, 0.22), (-1.38, 0.9, 0.36))]), color=(0.8, 0.72, 0.45)))
    # a checkered rug (1.2 cm thick) in front of the sofa, a ball on it
    rug = g.checker(512, 8, (0.62, 0.12, 0.1), (0.82, 0.78, 0.68))
    s.append(Shape("rug", g.box((-1.28, -0.6, 0.0), (-0.08, 0.6, 0.012)), texture=rug))
    s.append(Shape("ball", sphere=((-0.7, -0.25, 0.012 + 0.18), 0.18), color=(0.2, 0.42, 0.75)))
    # a table with a wood-striped top and thin legs, a few things on it
    wood = g.stripes(256, 24, (0.45, 0.3, 0.18), (0.5, 0.34, 0.2), vertical=False)
    top = 0.74
    s.append(Shape("tabletop", g.box((-0.2, 0.1, top - 0.04), (0.9, 0.8, top)), texture=wood))
    s.append(Shape("table_legs", g.merge([g.box((x - 0.025, y - 0.025, 0.0), (x + 0.025, y + 0.025, top - 0.04))
                                          for x in (-0.14, 0.84) for y in (0.16, 0.74)]), color=(0.3, 0.2, 0.12)))
    s += _mug(0.0, 0.3, top, 0.055, 0.11, (0.88, 0.88, 0.85), "mug", angle=210)
    bowl = g.lathe([(0.0, 0.0), (0.09, 0.0), (0.15, 0.045), (0.18, 0.1), (0.168, 0.1), (0.14, 0.055),
                    (0.085, 0.015), (0.0, 0.015)], n=96, samples=4)
    s.append(Shape("bowl", bowl.transformed(g.translate((0.45, 0.5, top))), color=(0.75, 0.4, 0.2)))
    s.append(Shape("orange", sphere=((0.43, 0.48, top + 0.015 + 0.065), 0.065), color=(0.85, 0.42, 0.06)))
    bottle = g.lathe([(0.0, 0.0), (0.055, 0.0), (0.06, 0.02), (0.06, 0.2), (0.04, 0.25), (0.02, 0.28),
                      (0.02, 0.35), (0.0, 0.35)], n=64, samples=4)
    s.append(Shape("bottle", bottle.transformed(g.translate((0.78, 0.68, top))), color=(0.12, 0.35, 0.18)))
    books = [_place(g.box((-0.15, -0.1, 0.0), (0.15, 0.1, 0.05)), g.translate((0.08, 0.64, top)), g.rot_z(8)),
             _place(g.box((-0.13, -0.09, 0.0), (0.13, 0.09, 0.06)), g.translate((0.07, 0.65, top + 0.05)), g.rot_z(-6))]
    s.append(Shape("books", g.merge(books), color=(0.6, 0.15, 0.12)))
    s.append(Shape("small_box", _place(g.box((-0.09, -0.06, 0.0), (0.09, 0.06, 0.1)), g.translate((0.7, 0.25, top)),
                                       g.rot_z(-30)), color=(0.55, 0.6, 0.8)))
    # a sideboard along the south wall with a vase on it
    s.append(Shape("sideboard", g.box((-0.4, -1.95, 0.0), (1.2, -1.55, 0.65)), color=(0.82, 0.8, 0.76)))
    vase = g.lathe([(0.0, 0.0), (0.07, 0.0), (0.11, 0.08), (0.1, 0.2), (0.05, 0.28), (0.06, 0.33), (0.0, 0.33)],
                   n=64, samples=6)
    s.append(Shape("vase", vase.transformed(g.translate((0.05, -1.75, 0.65))), color=(0.25, 0.3, 0.6)))
    # two stacked boxes on the floor near the east wall, turned differently
    s.append(Shape("crate", _place(g.box((-0.22, -0.22, 0.0), (0.22, 0.22, 0.44)), g.translate((1.6, -0.9, 0.0)),
                                   g.rot_z(25)), color=(0.8, 0.45, 0.15)))
    s.append(Shape("crate_top", _place(g.box((-0.13, -0.13, 0.0), (0.13, 0.13, 0.22)), g.translate((1.6, -0.9, 0.44)),
                                       g.rot_z(-10)),
                   texture=g.stripes(256, 8, (0.1, 0.2, 0.55), (0.9, 0.85, 0.6), vertical=True)))
    # a striped board leaning against the east wall (tilted 11 deg), lifted 3 mm off the floor
    board = g.box((-0.0125, -0.3, 0.0), (0.0125, 0.3, 1.2))
    s.append(Shape("board", _place(board, g.translate((1.75, 0.6, 0.003)), g.rot_y(11)),
                   texture=g.stripes(256, 6, (0.15, 0.25, 0.5), (0.85, 0.8, 0.6), vertical=False)))
    # a low floor lamp in the north-east corner: disc base, thin rod, open conical shade
    s.append(Shape("lamp_base", g.cylinder(0.16, 0.0, 0.03, 64).transformed(g.translate((1.65, 1.65, 0.0))),
                   color=(0.15, 0.15, 0.16)))
    s.append(Shape("lamp_rod", g.rod((1.65, 1.65, 0.03), (1.65, 1.65, 0.85), 0.018, 16), color=(0.15, 0.15, 0.16)))
    s.append(Shape("lamp_shade", g.lathe([(0.2, 0.8), (0.11, 1.05)], n=96, sharp=True)
                   .transformed(g.translate((1.65, 1.65, 0.0))), color=(0.9, 0.85, 0.65)))
    # a round pouf in the north-west corner
    s.append(Shape("pouf", g.cylinder(0.22, 0.0, 0.42, 64).transformed(g.translate((-1.55, 1.5, 0.0))),
                   color=(0.85, 0.68, 0.2)))
    return s


SCENES: dict[str, SceneSpec] = {}


def _add(spec: SceneSpec) -> None:
    SCENES[spec.name] = spec


_add(SceneSpec(
    name="occlusion",
    description=("Depth discontinuities of varied size: a pillar 2.6 units in front of the back wall, a "
                 "panel on a post at mid depth, a ball and a cube in front of it, a slab hung 0.12 in "
                 "front of the wall, a floating shelf and a low step. Plain albedo, so nearly every "
                 "image edge is an occlusion boundary. Forward-facing (LLFF-like) cameras."),
    layout="forward", aabb=((-4.5, -2.0, 0.0), (4.5, 3.0, 4.2)), near=1.5, far=9.0, fov_x=52.0, aspect=4 / 3,
    background="geometry", build=build_occlusion,
    cameras=forward_cameras(center=(0.0, -3.0, 1.2), half_extent=(0.7, 0.4), target=(0.0, 1.5, 0.95)),
    sun_dir=(0.5, 0.6, -0.62),
))

_add(SceneSpec(
    name="creases",
    description=("Polyhedra whose planar faces meet at sharp angles: a box, a triangular prism, a "
                 "four-step staircase, a square pyramid and an octahedron on a flat plate. Flat-shaded "
                 "(shading normal = face normal), so normals are piecewise constant with creases. "
                 "Object-centric cameras on the upper hemisphere (elevation 20-70 deg)."),
    layout="object", aabb=((-1.3, -1.3, -0.1), (1.3, 1.3, 1.0)), near=2.4, far=6.0, fov_x=40.0, aspect=1.0,
    background="transparent", build=build_creases,
    cameras=object_cameras(radius=4.0, target=(0.0, 0.0, 0.25), elev_min=20.0, elev_max=70.0),
))

_add(SceneSpec(
    name="texture",
    description=("Image edges that are not geometric edges: a checkerboard floor, a poster on the back "
                 "wall with block letters, a barcode band and stripes, a striped box and a flat board "
                 "with letters and bars. Depth and normals are smooth (planar) across every texture "
                 "edge. Forward-facing (LLFF-like) cameras."),
    layout="forward", aabb=((-4.5, -2.0, 0.0), (4.5, 3.0, 4.2)), near=2.0, far=9.0, fov_x=55.0, aspect=4 / 3,
    background="geometry", build=build_texture,
    cameras=forward_cameras(center=(0.0, -3.2, 1.3), half_extent=(0.75, 0.45), target=(0.0, 1.5, 1.0)),
    sun_dir=(0.35, 0.7, -0.62),
))

_add(SceneSpec(
    name="thin",
    description=("Thin structures down to about one pixel wide at 128x128: a picket fence, a row of "
                 "rods of decreasing radius (0.045 to 0.01), a wire-frame cube and an antenna mast with "
                 "cross-bars, on a plate. Object-centric cameras on the upper hemisphere "
                 "(elevation 20-70 deg)."),
    layout="object", aabb=((-1.3, -1.3, -0.1), (1.3, 1.3, 1.3)), near=2.4, far=6.0, fov_x=40.0, aspect=1.0,
    background="transparent", build=build_thin,
    cameras=object_cameras(radius=4.0, target=(0.0, 0.0, 0.35), elev_min=20.0, elev_max=70.0),
))

_add(SceneSpec(
    name="smooth",
    description=("Smooth surfaces with soft shading: an analytic sphere, a standing torus, an egg "
                 "(surface of revolution) and a bumpy mound (a heightfield with smooth normals that meets "
                 "the plate with zero slope) on a flat plate. Few image edges inside objects; normals vary "
                 "continuously. Object-centric cameras on the upper hemisphere (elevation 20-70 deg)."),
    layout="object", aabb=((-1.3, -1.3, -0.1), (1.3, 1.3, 1.0)), near=2.4, far=6.0, fov_x=40.0, aspect=1.0,
    background="transparent", build=build_smooth,
    cameras=object_cameras(radius=4.0, target=(0.0, 0.0, 0.2), elev_min=20.0, elev_max=70.0),
))

_add(SceneSpec(
    name="table",
    description=("A cluttered table against a wall, seen LLFF-style: camera centres on a small plane in "
                 "front, all facing forward. Books, mugs, a bowl with an orange, an apple, a bottle, a "
                 "plate, a small box, and a chair behind the table; wood-striped table top."),
    layout="forward", aabb=((-4.0, -1.2, 0.0), (4.0, 2.4, 3.2)), near=0.8, far=6.0, fov_x=50.0, aspect=4 / 3,
    background="geometry", build=build_table,
    cameras=forward_cameras(center=(0.0, -1.55, 1.45), half_extent=(0.35, 0.2), target=(0.0, 0.45, 0.82)),
    sun_dir=(0.45, 0.5, -0.74),
))

_add(SceneSpec(
    name="turntable",
    description=("One object, NeRF-synthetic style: a lighthouse (octagonal base, banded tower, gallery "
                 "with a thin railing, lantern and conical roof, door and windows) on a transparent "
                 "background. Training cameras at random on the upper hemisphere (elevation 5-75 deg), "
                 "test cameras on a ring at 25 deg elevation."),
    layout="turntable", aabb=((-0.6, -0.6, 0.0), (0.6, 0.6, 1.85)), near=2.0, far=4.6, fov_x=40.0, aspect=1.0,
    background="transparent", build=build_turntable,
    cameras=turntable_cameras(radius=3.3, target=(0.0, 0.0, 0.85), elev_min=5.0, elev_max=75.0, test_elev=25.0,
                              seed=3),
    sun_dir=(0.4, 0.5, -0.77),
))

_add(SceneSpec(
    name="room",
    description=("The inside of a small room (4 x 4 m floor, walls 2.4 m high, a different colour per "
                 "wall, no ceiling) seen from inside: a low sofa of boxes, a checkered rug with a ball, a "
                 "table with a mug, a bowl with an orange, a bottle, books and a box, a sideboard with a "
                 "vase, two stacked boxes, a striped board leaning on a wall, a floor lamp (thin rod and "
                 "open shade), a round pouf and a poster; plank-striped floor. Inward cameras on a circle "
                 "of radius 1.5 around the centre, training views over 240 deg so that three picked "
                 "views are ~120 deg apart; the aabb is the room plus 5 cm."),
    layout="inward", aabb=((-2.05, -2.05, -0.05), (2.05, 2.05, 2.45)), near=0.3, far=5.5, fov_x=60.0,
    aspect=4 / 3, background="geometry", build=build_room,
    cameras=inward_cameras(radius=1.5, height=1.4, height_var=0.1, target=(0.0, 0.0, 0.6)),
    sun_dir=(0.3, 0.4, -0.87),
))
