"""Furniture built from parts, and the paints of a home (procedural scenes, :mod:`panovocc_cli.datasets.rooms`).

Every piece is drawn in its local frame: origin at the centre of its footprint on the floor, front = +y,
up = +z, placed by a :class:`~panovocc_cli.datasets.meshbuild.Transform2D`. Each builder registers its
objects under Replica class names (``tv-screen``, ``lamp``, ``nightstand``, ...) and draws only from the
builder's random stream (book sizes, plant shapes), so a scene's bytes depend on the order of the calls.
"""

from __future__ import annotations

import numpy as np

from .meshbuild import Paint


# -------------------------------------------------------------------------------------------------
# Palettes
# -------------------------------------------------------------------------------------------------
def pick(rng, options):
    """One of ``options``, drawn from ``rng``."""
    return options[int(rng.integers(len(options)))]


def paints(rng) -> dict[str, Paint]:
    """A home's paints by role (``wall``, ``floor``, ``wood``, ``fabric``, ...), some drawn from ``rng``."""
    wall = pick(rng, [(232, 228, 218), (214, 220, 224), (226, 214, 196), (205, 218, 205), (238, 236, 232)])
    floor = pick(rng, [(168, 118, 74), (120, 82, 54), (196, 166, 124), (150, 140, 128)])
    wood = pick(rng, [(150, 105, 65), (95, 62, 40), (190, 160, 120), (60, 50, 45)])
    fabric = pick(rng, [(110, 118, 130), (70, 90, 120), (120, 135, 95), (150, 120, 95), (160, 60, 55)])
    return {
        "wall": Paint(wall, jitter=0.012, noise=0.035),
        "ceiling": Paint((240, 240, 238), jitter=0.008, noise=0.02),
        "floor": Paint(floor, jitter=0.09, noise=0.06),
        "wood": Paint(wood, jitter=0.05, noise=0.08),
        "white": Paint((235, 235, 230), jitter=0.01, noise=0.02),
        "metal": Paint((70, 72, 76), jitter=0.02, noise=0.03),
        "fabric": Paint(fabric, jitter=0.04, noise=0.07),
        "cushion": Paint(tuple(min(255, c * 1.25) for c in fabric), jitter=0.03, noise=0.06),
        "sheet": Paint(pick(rng, [(236, 234, 228), (200, 210, 226), (226, 210, 200)]), jitter=0.02, noise=0.05),
        "blanket": Paint(pick(rng, [(90, 110, 150), (170, 90, 80), (120, 140, 110)]), jitter=0.03, noise=0.08,
                         stripes=0.18, stripe_rgb=(200, 200, 190)),
        "pillow": Paint((245, 244, 238), jitter=0.02, noise=0.04),
        "glass": Paint((150, 185, 205), jitter=0.01, noise=0.03),
        "frame": Paint((245, 245, 245), jitter=0.01, noise=0.02),
        "door": Paint(pick(rng, [(240, 238, 232), (140, 96, 60), (200, 180, 150)]), jitter=0.015, noise=0.04),
        "screen": Paint((22, 24, 30), jitter=0.01, noise=0.05),
        "light": Paint((252, 248, 232), jitter=0.005, noise=0.01),
        "shade": Paint((240, 226, 190), jitter=0.01, noise=0.03),
        "curtain": Paint(pick(rng, [(200, 190, 170), (120, 130, 150), (170, 120, 110), (225, 222, 210)]),
                         jitter=0.04, noise=0.08),
        "rug": Paint(pick(rng, [(150, 50, 45), (60, 80, 130), (190, 170, 130)]), jitter=0.05, noise=0.06,
                     stripes=0.25, stripe_rgb=(pick(rng, [(220, 210, 180), (40, 40, 50), (120, 30, 30)]))),
        "leaf": Paint((60, 120, 55), jitter=0.12, noise=0.15),
        "pot": Paint((170, 95, 60), jitter=0.03, noise=0.05),
        "cabinet": Paint(pick(rng, [(235, 235, 230), wood, (90, 100, 110)]), jitter=0.02, noise=0.05),
        "handle": Paint((180, 180, 185), jitter=0.01, noise=0.02),
    }


# -------------------------------------------------------------------------------------------------
# Furniture (local frame: origin at the footprint centre on the floor, front = +y, up = +z)
# -------------------------------------------------------------------------------------------------
def table(mb, pt, tf, w, d, h, leg=0.05, cls="table"):
    """A table: top ``w`` x ``d`` at height ``h`` on four legs (metres)."""
    o = mb.new_object(cls)
    mb.box(o, pt["wood"], (0, 0, h - 0.02), (w, d, 0.04), tf, cell=0.2)
    for sx in (-1, 1):
        for sy in (-1, 1):
            mb.box(o, pt["wood"], (sx * (w / 2 - 0.06), sy * (d / 2 - 0.06), (h - 0.04) / 2), (leg, leg, h - 0.04),
                   tf, omit=("-z", "+z"), cell=0.2)


def chair(mb, tf, paint):
    """A chair (44 cm seat, open back), facing +y."""
    o = mb.new_object("chair")
    sw, sh = 0.44, 0.46
    mb.box(o, paint, (0, 0, sh - 0.02), (sw, sw, 0.04), tf, cell=0.15)
    for sx in (-1, 1):
        for sy in (-1, 1):
            mb.box(o, paint, (sx * (sw / 2 - 0.03), sy * (sw / 2 - 0.03), (sh - 0.04) / 2), (0.035, 0.035, sh - 0.04),
                   tf, omit=("-z", "+z"), cell=0.2)
        mb.box(o, paint, (sx * (sw / 2 - 0.03), -sw / 2 + 0.0175, sh + 0.22), (0.035, 0.035, 0.44), tf,
               omit=("-z",), cell=0.2)
    mb.box(o, paint, (0, -sw / 2 + 0.0175, sh + 0.33), (sw - 0.07, 0.025, 0.2), tf, cell=0.15)


def sofa(mb, pt, tf, w, d=0.9):
    """A sofa ``w`` x ``d`` metres: base, two or three seat cushions, back, arms, and ``cushion`` blobs."""
    o = mb.new_object("sofa")
    f = pt["fabric"]
    arm, bt, sh = 0.18, 0.22, 0.42
    mb.box(o, f, (0, bt / 2, 0.16), (w - 2 * arm, d - bt, 0.32), tf, omit=("-z",), cell=0.2)
    n = 2 if w < 1.9 else 3
    cw = (w - 2 * arm) / n
    for k in range(n):
        x = -w / 2 + arm + (k + 0.5) * cw
        mb.box(o, f, (x, bt / 2 + 0.01, (0.32 + sh) / 2), (cw - 0.015, d - bt - 0.02, sh - 0.32), tf, omit=("-z",),
               cell=0.15)
    mb.box(o, f, (0, -d / 2 + bt / 2, 0.43), (w, bt, 0.86), tf, omit=("-z", "-y"), cell=0.2)
    for sx in (-1, 1):
        mb.box(o, f, (sx * (w / 2 - arm / 2), bt / 2, 0.31), (arm, d - bt, 0.62), tf, omit=("-z",), cell=0.15)
    c = mb.new_object("cushion")
    for k in range(n):
        x = -w / 2 + arm + (k + 0.5) * cw
        mb.blob(c, pt["cushion"], (x, -d / 2 + bt + 0.08, sh + 0.22), (min(0.24, cw / 2 - 0.04), 0.07, 0.2), n=3,
                bumpiness=0.06, tf=tf)


def bed(mb, pt, tf, w, L):
    """A bed ``w`` x ``L`` metres: frame, mattress, blanket, headboard (at -y), ``pillow`` blobs."""
    o = mb.new_object("bed")
    mb.box(o, pt["wood"], (0, 0.03, 0.15), (w, L - 0.06, 0.3), tf, omit=("-z",), cell=0.25)
    mb.box(o, pt["sheet"], (0, 0.03, 0.43), (w - 0.04, L - 0.1, 0.26), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["blanket"], (0, L * 0.18, 0.575), (w - 0.02, L * 0.6, 0.03), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["wood"], (0, -L / 2 + 0.03, 0.52), (w, 0.06, 1.04), tf, omit=("-z", "-y"), cell=0.2)
    p = mb.new_object("pillow")
    n = 1 if w < 1.3 else 2
    for k in range(n):
        x = (k - (n - 1) / 2) * (w / n)
        mb.blob(p, pt["pillow"], (x, -L / 2 + 0.3, 0.64), (min(0.3, w / (2 * n) - 0.05), 0.18, 0.07), n=3,
                bumpiness=0.05, tf=tf)


def cabinet(mb, pt, tf, w, d, h, cls="cabinet", doors=2):
    """A cabinet ``w`` x ``d`` x ``h`` metres against a wall (at -y), ``doors`` door panels with handles."""
    o = mb.new_object(cls)
    paint = pt["cabinet"]
    mb.box(o, paint, (0, 0, h / 2), (w, d, h), tf, omit=("-z", "-y"), cell=0.2)
    dw = w / doors
    for k in range(doors):
        x = -w / 2 + (k + 0.5) * dw
        mb.box(o, paint, (x, d / 2 + 0.01, h / 2), (dw - 0.012, 0.02, h - 0.04), tf, omit=("-y",), cell=0.2)
        hx = x + (0.35 if k % 2 == 0 else -0.35) * dw
        mb.box(o, pt["handle"], (hx, d / 2 + 0.035, h * 0.55), (0.02, 0.03, min(0.15, h * 0.3)), tf, omit=("-y",),
               cell=0.2)


def tv(mb, pt, tf, w, z0):
    """A ``tv-screen`` ``w`` metres wide on a foot standing at height ``z0``."""
    o = mb.new_object("tv-screen")
    h = w * 0.58
    mb.box(o, pt["metal"], (0, 0, z0 + 0.01), (0.32, 0.2, 0.02), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["metal"], (0, 0, z0 + 0.07), (0.06, 0.03, 0.1), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["screen"], (0, 0.0, z0 + 0.12 + h / 2), (w, 0.05, h), tf, cell=0.2)


def floor_lamp(mb, pt, tf):
    """A floor ``lamp``: base, pole, shade (1.66 m)."""
    o = mb.new_object("lamp")
    mb.cylinder(o, pt["metal"], (0, 0), 0.0, 0.03, 0.15, n=12, tf=tf)
    mb.cylinder(o, pt["metal"], (0, 0), 0.03, 1.38, 0.015, n=8, top=False, tf=tf)
    mb.cylinder(o, pt["shade"], (0, 0), 1.38, 1.66, 0.21, n=16, top=True, radius_top=0.15, tf=tf)


def table_lamp(mb, pt, tf, z0):
    """A table ``lamp`` standing at height ``z0``."""
    o = mb.new_object("lamp")
    mb.cylinder(o, pt["pot"], (0, 0), z0, z0 + 0.25, 0.06, n=12, top=False, tf=tf)
    mb.cylinder(o, pt["shade"], (0, 0), z0 + 0.25, z0 + 0.45, 0.15, n=16, top=True, radius_top=0.1, tf=tf)


def plant(mb, pt, tf, rng):
    """A ``plant``: pot, stem and foliage blobs, sizes drawn from ``rng``."""
    o = mb.new_object("plant")
    r = rng.uniform(0.14, 0.19)
    hp = rng.uniform(0.3, 0.42)
    mb.cylinder(o, pt["pot"], (0, 0), 0.0, hp, r, n=12, top=True, radius_top=r * 1.15, tf=tf)
    mb.cylinder(o, pt["wood"], (0, 0), hp, hp + 0.35, 0.015, n=8, top=False, tf=tf)
    for k in range(3):
        c = (rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06), hp + 0.35 + 0.22 * k)
        rr = rng.uniform(0.18, 0.27) * (1.0 - 0.2 * k)
        mb.blob(o, pt["leaf"], c, (rr, rr, rr * 0.9), n=4, bumpiness=0.25, tf=tf)


def bookshelf(mb, pt, tf, rng, w, h=1.8, d=0.32):
    """A ``shelf`` ``w`` x ``d`` x ``h`` metres against a wall, its shelves filled with ``book``s drawn from ``rng``."""
    o = mb.new_object("shelf")
    p = pt["wood"]
    for sx in (-1, 1):
        mb.box(o, p, (sx * (w / 2 - 0.01), 0, h / 2), (0.02, d, h), tf, omit=("-z", "-y"), cell=0.2)
    mb.box(o, p, (0, -d / 2 + 0.005, h / 2), (w - 0.04, 0.01, h), tf, omit=("-y",), cell=0.2)
    levels = np.linspace(0.02, h - 0.01, 5)
    for z in levels:
        mb.box(o, p, (0, 0, z), (w - 0.04, d - 0.01, 0.02), tf, cell=0.2)
    b = mb.new_object("book")
    for z in levels[:-1]:
        x = -w / 2 + 0.04
        while True:
            bw = rng.uniform(0.02, 0.05)
            if x + bw > w / 2 - 0.06:
                break
            bh = rng.uniform(0.18, 0.28)
            col = tuple(float(c) for c in rng.uniform(40, 220, 3).round())
            mb.box(b, Paint(col, jitter=0.02, noise=0.03), (x + bw / 2, 0.0, z + 0.01 + bh / 2), (bw, 0.2, bh), tf,
                   omit=("-z",), cell=0.3)
            x += bw + rng.uniform(0.0, 0.01)


def rug(mb, pt, tf, w, d):
    """A 1 cm ``rug`` ``w`` x ``d`` metres."""
    o = mb.new_object("rug")
    mb.box(o, pt["rug"], (0, 0, 0.005), (w, d, 0.01), tf, omit=("-z",), cell=0.12)

