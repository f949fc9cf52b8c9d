#!/usr/bin/env python3
"""Two held-out scenes for the object presets, kept aside like `den` is for the rooms:
their renders are not committed and no setting is chosen on them. They exist to
measure what was tuned on the committed object and forward-facing scenes
(docs/results/geometry.md) on scenes and camera layouts that were not.

* ``workshop`` - object-centric: a tool chest, a barrel, a cone, a stool and a mallet on
  a round plate, seen from a lower, closer band (elevation 12-55 deg, radius 3.4) than
  the committed object scenes' 20-70 deg at 4.0.
* ``hallway``  - forward-facing: a corridor's floor and back wall with a doorway, a
  bench, an umbrella stand, a hanging lamp and a rug, seen from a rig wider and
  lower than the committed forward scenes'.

Renders the small preset (24 + 8 views) with the repository's render.py and its venv:

    synthetic-scenes/.venv/bin/python synthetic-scenes/heldout/objects.py OUT_ROOT
    # -> OUT_ROOT/workshop and OUT_ROOT/hallway, Blender-format scenes for `edgenerf train`
    # (names after OUT_ROOT render only those)
"""
import sys
from pathlib import Path
HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))
import numpy as np
import geometry as g
import scenes as S
from scenes import Shape, SceneSpec


def build_workshop():
    plate = g.cylinder(1.2, -0.06, 0.0, 96)
    s = [Shape("plate", plate, color=(0.5, 0.48, 0.44))]
    # a tool chest of three drawers, the middle one pulled out
    chest = [g.box((-0.75, -0.2, 0.0), (-0.25, 0.15, 0.12)), g.box((-0.75, -0.2, 0.24), (-0.25, 0.15, 0.36))]
    chest += [g.box((-0.75, -0.28, 0.12), (-0.25, 0.15, 0.24))]
    s.append(Shape("chest", g.merge(chest), color=(0.72, 0.16, 0.14)))
    handles = [g.box((-0.58, -0.31, 0.17), (-0.42, -0.28, 0.17 + 0.025))]  # the pulled-out drawer's
    handles += [g.box((-0.58, -0.23, y), (-0.42, -0.2, y + 0.025)) for y in (0.05, 0.29)]
    s.append(Shape("handles", g.merge(handles),
                   color=(0.8, 0.8, 0.78)))
    # a barrel with hoops
    barrel = g.lathe([(0.0, 0.0), (0.2, 0.0), (0.24, 0.22), (0.2, 0.44), (0.0, 0.44)], n=64, samples=6)
    s.append(Shape("barrel", barrel.transformed(g.translate((0.45, 0.45, 0.0))),
                   texture=g.stripes(256, 14, (0.55, 0.36, 0.2), (0.45, 0.28, 0.15), vertical=True)))
    s.append(Shape("hoops", g.merge([g.torus(0.225, 0.012).transformed(g.translate((0.45, 0.45, z)))
                                     for z in (0.1, 0.34)]), color=(0.25, 0.25, 0.27)))
    # a traffic cone, striped
    cone = g.lathe([(0.0, 0.0), (0.16, 0.0), (0.03, 0.5), (0.0, 0.5)], n=64, samples=4)
    s.append(Shape("cone", cone.transformed(g.translate((0.55, -0.5, 0.0))),
                   texture=g.stripes(256, 6, (0.95, 0.45, 0.1), (0.95, 0.95, 0.92), vertical=False)))
    # a three-legged stool
    stool = [g.cylinder(0.18, 0.38, 0.42, 48).transformed(g.translate((-0.35, 0.6, 0.0)))]
    for k in range(3):
        a = np.radians(120 * k + 20)
        x, y = -0.35 + 0.13 * np.cos(a), 0.6 + 0.13 * np.sin(a)
        stool.append(g.rod((x, y, 0.0), (-0.35 + 0.1 * np.cos(a), 0.6 + 0.1 * np.sin(a), 0.38), 0.018, 12))
    s.append(Shape("stool", g.merge(stool), color=(0.78, 0.62, 0.38)))
    # a mallet lying on the plate
    s.append(Shape("mallet_head", g.box((0.02, -0.08, 0.0), (0.14, 0.12, 0.1)), color=(0.3, 0.45, 0.6)))
    s.append(Shape("mallet_handle", g.rod((0.08, 0.02, 0.05), (-0.05, 0.5, 0.03), 0.015, 12), color=(0.6, 0.45, 0.3)))
    # a ball on the stool
    s.append(Shape("ball", sphere=((-0.33, 0.58, 0.52), 0.1), color=(0.2, 0.6, 0.35)))
    return s


def build_hallway():
    s = []
    floor = g.quad((-3.5, -1.5, 0), (3.5, -1.5, 0), (3.5, 4.0, 0), (-3.5, 4.0, 0), uv_scale=(3.0, 2.4))
    s.append(Shape("floor", floor, texture=g.stripes(256, 20, (0.62, 0.5, 0.36), (0.55, 0.43, 0.3), vertical=True)))
    # the back wall with a doorway: three panels around a dark opening, a frame
    W, H = 3.0, 4.2
    s.append(Shape("wall_left", g.quad((-3.5, W, 0), (-0.5, W, 0), (-0.5, W, H), (-3.5, W, H)), color=(0.82, 0.8, 0.72)))
    s.append(Shape("wall_right", g.quad((0.5, W, 0), (3.5, W, 0), (3.5, W, H), (0.5, W, H)), color=(0.82, 0.8, 0.72)))
    s.append(Shape("wall_top", g.quad((-0.5, W, 2.1), (0.5, W, 2.1), (0.5, W, H), (-0.5, W, H)), color=(0.82, 0.8, 0.72)))
    s.append(Shape("doorway_back", g.quad((-0.5, W + 1.0, 0), (0.5, W + 1.0, 0), (0.5, W + 1.0, 2.1),
                                          (-0.5, W + 1.0, 2.1)), color=(0.25, 0.27, 0.3)))
    passage = [g.quad((-0.5, W + 1.0, 0), (-0.5, W, 0), (-0.5, W, 2.1), (-0.5, W + 1.0, 2.1)),
               g.quad((0.5, W, 0), (0.5, W + 1.0, 0), (0.5, W + 1.0, 2.1), (0.5, W, 2.1)),
               g.quad((-0.5, W, 2.1), (0.5, W, 2.1), (0.5, W + 1.0, 2.1), (-0.5, W + 1.0, 2.1))]
    s.append(Shape("passage", g.merge(passage), color=(0.5, 0.48, 0.45)))
    s.append(Shape("door_frame", g.merge([g.box((-0.6, W - 0.05, 0.0), (-0.5, W, 2.2)),
                                          g.box((0.5, W - 0.05, 0.0), (0.6, W, 2.2)),
                                          g.box((-0.6, W - 0.05, 2.1), (0.6, W, 2.2))]), color=(0.4, 0.3, 0.22)))
    # a bench along the left, an umbrella stand on the right
    bench = [g.box((-2.4, 1.6, 0.42), (-1.0, 2.0, 0.48))]
    bench += [g.box((x, 1.65, 0.0), (x + 0.06, 1.95, 0.42)) for x in (-2.35, -1.11)]
    s.append(Shape("bench", g.merge(bench), color=(0.3, 0.2, 0.12)))
    s.append(Shape("stand", g.cylinder(0.16, 0.0, 0.55, 48).transformed(g.translate((1.5, 2.3, 0.0))),
                   color=(0.2, 0.35, 0.5)))
    s.append(Shape("umbrella", g.rod((1.5, 2.3, 0.3), (1.6, 2.35, 1.05), 0.02, 12), color=(0.1, 0.1, 0.1)))
    # a box on the bench and a hat beside it
    s.append(Shape("shoebox", g.box((-2.2, 1.65, 0.48), (-1.75, 1.95, 0.66)), color=(0.9, 0.85, 0.7)))
    hat = g.lathe([(0.0, 0.0), (0.2, 0.0), (0.2, 0.01), (0.1, 0.02), (0.09, 0.14), (0.0, 0.14)], n=64, samples=4)
    s.append(Shape("hat", hat.transformed(g.translate((-1.4, 1.8, 0.48))), color=(0.55, 0.15, 0.2)))
    # a lamp hanging from above on a cord, and a rug on the floor
    s.append(Shape("cord", g.rod((0.9, 1.0, 4.2), (0.9, 1.0, 2.2), 0.008, 8), color=(0.1, 0.1, 0.1)))
    shade = g.lathe([(0.03, 0.0), (0.22, -0.25), (0.0, -0.25)], n=64, samples=4)
    s.append(Shape("shade", shade.transformed(g.translate((0.9, 1.0, 2.2))), color=(0.95, 0.85, 0.4)))
    s.append(Shape("rug", g.box((-0.9, 0.0, 0.0), (0.9, 1.6, 0.012)),
                   texture=g.checker(256, 6, (0.6, 0.2, 0.2), (0.85, 0.8, 0.7))))
    return s


S._add(SceneSpec(
    name="workshop",
    description="held-out object-centric scene (not committed)",
    layout="object", aabb=((-1.25, -1.25, -0.1), (1.25, 1.25, 0.9)), near=2.0, far=5.5, fov_x=42.0,
    aspect=1.0, background="transparent", build=build_workshop,
    cameras=S.object_cameras(radius=3.4, target=(0.0, 0.0, 0.2), elev_min=12.0, elev_max=55.0),
))

S._add(SceneSpec(
    name="hallway",
    description="held-out forward-facing scene (not committed)",
    layout="forward", aabb=((-3.5, -1.5, 0.0), (3.5, 4.05, 4.25)), near=1.0, far=8.0, fov_x=58.0,
    aspect=4 / 3, background="geometry", build=build_hallway,
    cameras=S.forward_cameras(center=(0.0, -2.2, 1.0), half_extent=(0.95, 0.3), target=(0.0, 2.0, 0.9)),
    sun_dir=(-0.4, 0.55, -0.73),
))
import render
sys.exit(render.main(["--scene", *(sys.argv[2:] or ["workshop", "hallway"]), "--out", sys.argv[1]]))
