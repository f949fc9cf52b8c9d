#!/usr/bin/env python3
"""A held-out inside-out scene, `den`: a 5 x 3.6 m room seen from within, with
furniture, walls and a camera circle unlike `room`'s. Its renders are not committed and
no setting is chosen on it: it exists to measure what was tuned on `room` on a scene
that was not (docs/results/real-captures.md, "Rooms seen from within"). Renders the
small preset (24 + 8 views, 128 x 96) with the repository's render.py and its venv:

    synthetic-scenes/.venv/bin/python synthetic-scenes/heldout/den.py OUT_ROOT
    # -> OUT_ROOT/den, a Blender-format scene for `edgenerf train`
"""
import sys
from pathlib import Path
HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))
import numpy as np
import geometry as g
import scenes as S
from scenes import Shape, SceneSpec

def build_den():
    X, Y, H = 2.5, 1.8, 2.6
    tiles = g.checker(512, 10, (0.55, 0.52, 0.46), (0.4, 0.38, 0.35))
    s = [Shape("floor", g.quad((-X, -Y, 0), (X, -Y, 0), (X, Y, 0), (-X, Y, 0)), texture=tiles)]
    walls = (("north", (X, Y), (-X, Y), None, (0.7, 0.55, 0.35)),
             ("west", (-X, Y), (-X, -Y), g.stripes(256, 16, (0.45, 0.55, 0.5), (0.6, 0.68, 0.62), vertical=True), None),
             ("south", (-X, -Y), (X, -Y), None, (0.5, 0.5, 0.62)),
             ("east", (X, -Y), (X, Y), None, (0.78, 0.74, 0.7)))
    for name, p0, p1, tex, col in walls:
        q = g.quad((*p0, 0), (*p1, 0), (*p1, H), (*p0, H))
        s.append(Shape("wall_" + name, q, texture=tex) if tex is not None else Shape("wall_" + name, q, color=col))
    # a bed along the east wall: frame, mattress, pillow
    s.append(Shape("bed_frame", g.box((1.0, -1.75, 0.0), (2.45, 0.2, 0.3)), color=(0.35, 0.22, 0.14)))
    s.append(Shape("mattress", g.box((1.05, -1.7, 0.3), (2.4, 0.15, 0.48)),
                   texture=g.stripes(256, 12, (0.85, 0.85, 0.9), (0.55, 0.6, 0.8), vertical=False)))
    s.append(Shape("pillow", g.box((1.15, -0.25, 0.48), (2.3, 0.1, 0.6)), color=(0.92, 0.9, 0.85)))
    # a bookshelf on the north wall: sides, shelves, coloured books
    shelf = [g.box((-1.6, 1.45, 0.0), (-1.55, 1.78, 1.6)), g.box((-0.45, 1.45, 0.0), (-0.4, 1.78, 1.6))]
    shelf += [g.box((-1.6, 1.45, z), (-0.4, 1.78, z + 0.03)) for z in (0.0, 0.5, 1.0, 1.57)]
    s.append(Shape("shelf", g.merge(shelf), color=(0.8, 0.78, 0.72)))
    rng = np.random.default_rng(7)
    for i, z in enumerate((0.03, 0.53, 1.03)):
        x = -1.53
        k = 0
        while x < -0.5:
            w = 0.04 + 0.04 * rng.random()
            h = 0.25 + 0.15 * rng.random()
            col = tuple(float(c) for c in rng.uniform(0.1, 0.85, 3))
            s.append(Shape(f"book_{i}_{k}", g.box((x, 1.5, z), (min(x + w, -0.46), 1.76, z + h)), color=col))
            x += w + 0.01
            k += 1
    # a round table with a ball and a ring on it
    s.append(Shape("table_top", g.cylinder(0.45, 0.66, 0.7, 64).transformed(g.translate((-0.9, -0.6, 0.0))),
                   color=(0.62, 0.42, 0.26)))
    s.append(Shape("table_leg", g.rod((-0.9, -0.6, 0.0), (-0.9, -0.6, 0.66), 0.04, 16), color=(0.2, 0.18, 0.16)))
    s.append(Shape("ball", sphere=((-0.8, -0.5, 0.7 + 0.12), 0.12), color=(0.85, 0.2, 0.2)))
    s.append(Shape("ring", g.torus(0.09, 0.025).transformed(g.translate((-1.1, -0.75, 0.725))), color=(0.2, 0.5, 0.3)))
    # a chair of boxes
    chair = [g.box((-1.75, -0.9, 0.42), (-1.35, -0.4, 0.47)), g.box((-1.78, -0.9, 0.47), (-1.73, -0.4, 0.95))]
    chair += [g.box((x - 0.02, y - 0.02, 0.0), (x + 0.02, y + 0.02, 0.42)) for x in (-1.72, -1.38) for y in (-0.87, -0.43)]
    s.append(Shape("chair", g.merge(chair), color=(0.25, 0.32, 0.55)))
    # a potted plant by the south-west corner: pot and a round crown on a stem
    pot = g.lathe([(0.0, 0.0), (0.12, 0.0), (0.16, 0.3), (0.0, 0.3)], n=64, samples=4)
    s.append(Shape("pot", pot.transformed(g.translate((-2.1, -1.4, 0.0))), color=(0.7, 0.35, 0.2)))
    s.append(Shape("stem", g.rod((-2.1, -1.4, 0.3), (-2.1, -1.4, 0.9), 0.015, 12), color=(0.3, 0.25, 0.1)))
    s.append(Shape("crown", sphere=((-2.1, -1.4, 1.1), 0.25), color=(0.2, 0.5, 0.2)))
    # a low cabinet in the middle of the south wall with a pyramid on it
    s.append(Shape("cabinet", g.box((-0.3, -1.78, 0.0), (0.6, -1.4, 0.55)), color=(0.3, 0.3, 0.32)))
    s.append(Shape("pyramid", g.pyramid(0.25, 0.3).transformed(g.translate((0.15, -1.6, 0.55))), color=(0.9, 0.8, 0.3)))
    # a rug under the table
    s.append(Shape("rug", g.box((-1.5, -1.2, 0.0), (-0.2, 0.1, 0.01)),
                   texture=g.stripes(256, 10, (0.2, 0.3, 0.6), (0.85, 0.75, 0.55), vertical=True)))
    return s

S._add(SceneSpec(
    name="den",
    description="held-out inside-out room (not committed)",
    layout="inward", aabb=((-2.55, -1.85, -0.05), (2.55, 1.85, 2.65)), near=0.3, far=6.5, fov_x=60.0,
    aspect=4 / 3, background="geometry", build=build_den,
    cameras=S.inward_cameras(radius=1.1, height=1.3, height_var=0.12, target=(0.1, -0.1, 0.55), arc_deg=260.0,
                             test_phase_deg=17.0),
    sun_dir=(0.35, -0.3, -0.89),
))
import render
sys.exit(render.main(["--scene", "den", "--out", sys.argv[1]]))
