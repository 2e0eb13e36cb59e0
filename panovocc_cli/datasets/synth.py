"""Procedural indoor scenes in Replica's format, with a camera trajectory through every room.

A scene is one to six rooms on a grid (a row for up to three), separated by 12 cm thick walls. Rooms
that follow each other in a snake order share an interior door (an open leaf swung into one room);
the first room has a closed entrance door; every room has windows in its exterior walls (holes with
reveals, glass panes, frames, curtains). Furniture is built from parts (legs, seats, backs, arms,
headboards, pillows, cushions, shelves, books) and placed against walls or around tables, clear of
doors and windows. Colours are per-vertex with per-object tint, per-cell jitter (planks, tiles) and
smooth variation, like a scan's texture. Surfaces face the room; nothing is double-sided.

The trajectory visits every room (through the door openings) on a clearance-weighted shortest path
over a 5 cm occupancy raster, smoothed and kept at least 0.3 m from walls and furniture, at 1.2-1.7 m
height with small pitch and roll. Everything is drawn from ``np.random.default_rng(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..classes import EVAL8, OPEN4, canonical_name
from ..config import DEFAULT_SEED, option, validate_config
from ..errors import PanovoccError
from ..geometry.poses import look_at
from .meshbuild import MeshBuilder, Paint, Transform2D

WALL_T = 0.12  # wall thickness, metres
CLEARANCE = 0.30  # minimum camera distance to walls and furniture, metres
PLAN_CLEARANCE = 0.33  # clearance demanded of the raster path (margin for smoothing)
RASTER = 0.05  # planning raster, metres
CAM_Z = (1.2, 1.7)  # camera height range above the floor, metres
SHIFT_STREAM = 104729  # random stream of the home's offset from the origin (see generate_scene)
MAX_TILT_DEG = 6.0  # |pitch| and |roll| bound of the trajectory, degrees
MAX_ROOMS = 6

_NORMAL = {"S": (0.0, 1.0), "N": (0.0, -1.0), "W": (1.0, 0.0), "E": (-1.0, 0.0)}
_OPPOSITE = {"S": "N", "N": "S", "W": "E", "E": "W"}


class _Retry(Exception):
    """A layout draw that cannot be furnished or traversed; the generator draws again."""


@dataclass
class SynthConfig:
    """Options of ``panovocc synth``.

    out: scene folder to write (Replica layout); seed: random seed; rooms: number of rooms (None:
    2 or 3 drawn from the seed; 6-8 with ``house``); frames: trajectory poses (None: 60, or 300 with
    ``house``); offset: (x, y, z) metres the home is moved from the origin (a user-chosen placement
    relative to the voxel lattice; None: drawn from the seed); house: a house-scale home
    (:mod:`panovocc_cli.datasets.house`).
    """

    out: Path = option(argument=True, metavar="SCENE", help="Scene folder to write (Replica layout: "
                       "habitat/mesh_semantic.ply, habitat/info_semantic.json, traj.txt).")
    seed: int = option(DEFAULT_SEED, min=0, help="Random seed; the same seed gives the same files.")
    rooms: int | None = option(None, min=1, max=8, help="Number of rooms, 1-6 (default: 2 or 3 from the seed); "
                               "with --house 6-8 off a corridor (default: 6, 7 or 8 from the seed).")
    frames: int | None = option(None, min=2, show_default="60; 300 with --house",
                                help="Number of trajectory poses.")
    offset: tuple[float, float, float] | None = option(
        None, cli_type=str, parse=lambda text: parse_offset(text), metavar="X,Y,Z",
        help="X,Y,Z metres: move the home (laid out from the origin) by this offset instead of the seeded one "
             "(e.g. 0,0,0 puts the floor on a voxel face).")
    house: bool = option(False, help="A house-scale home: 6-8 furnished rooms on both sides of a corridor, a long "
                                     "trajectory through all of them (the embedded Pan-Holo split's scene).")
    overwrite: bool = option(False, help="Replace a previous panovocc scene in SCENE (never any other folder).")


@dataclass
class Opening:
    kind: str  # "door" (interior, open leaf), "entrance" (closed leaf) or "window"
    side: str
    s0: float
    s1: float
    z0: float
    z1: float
    other: int | None = None
    owner: bool = True  # builds the reveals/tunnel
    leaf_here: bool = False  # the open leaf stands in this room
    hinge_s0: bool = True


@dataclass
class Room:
    idx: int
    kind: str
    x0: float
    x1: float
    y0: float
    y1: float
    openings: list[Opening] = field(default_factory=list)
    shared: dict[str, int] = field(default_factory=dict)

    def side_range(self, side: str) -> tuple[float, float]:
        return (self.x0, self.x1) if side in "SN" else (self.y0, self.y1)

    def P(self, side: str, s, o, z) -> np.ndarray:
        """World point at ``s`` along the wall, ``o`` metres outward from its room face, height ``z``."""
        s, o, z = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (s, o, z)))
        if side == "S":
            return np.stack([s, self.y0 - o, z], -1)
        if side == "N":
            return np.stack([s, self.y1 + o, z], -1)
        if side == "W":
            return np.stack([self.x0 - o, s, z], -1)
        return np.stack([self.x1 + o, s, z], -1)

    def aabb(self, side: str, s0, s1, o0, o1) -> tuple[float, float, float, float]:
        """2-D box (x0, x1, y0, y1) of wall coordinates s in [s0, s1], o in [o0, o1]."""
        p = self.P(side, [s0, s1], [o0, o1], [0.0, 0.0])
        return (min(p[:, 0]), max(p[:, 0]), min(p[:, 1]), max(p[:, 1]))

    @property
    def center(self) -> np.ndarray:
        return np.array([(self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2])


def _overlap(a, b, gap=0.0) -> bool:
    return a[0] < b[1] + gap and b[0] < a[1] + gap and a[2] < b[3] + gap and b[2] < a[3] + gap


# -------------------------------------------------------------------------------------------------
# Palettes
# -------------------------------------------------------------------------------------------------
def _pick(rng, options):
    return options[int(rng.integers(len(options)))]


def _paints(rng) -> dict[str, Paint]:
    wall = _pick(rng, [(232, 228, 218), (214, 220, 224), (226, 214, 196), (205, 218, 205), (238, 236, 232)])
    floor = _pick(rng, [(168, 118, 74), (120, 82, 54), (196, 166, 124), (150, 140, 128)])
    wood = _pick(rng, [(150, 105, 65), (95, 62, 40), (190, 160, 120), (60, 50, 45)])
    fabric = _pick(rng, [(110, 118, 130), (70, 90, 120), (120, 135, 95), (150, 120, 95), (160, 60, 55)])
    return {
        "wall": Paint(wall, jitter=0.012, noise=0.035),
        "ceiling": Paint((240, 240, 238), jitter=0.008, noise=0.02),
        "floor": Paint(floor, jitter=0.09, noise=0.06),
        "wood": Paint(wood, jitter=0.05, noise=0.08),
        "white": Paint((235, 235, 230), jitter=0.01, noise=0.02),
        "metal": Paint((70, 72, 76), jitter=0.02, noise=0.03),
        "fabric": Paint(fabric, jitter=0.04, noise=0.07),
        "cushion": Paint(tuple(min(255, c * 1.25) for c in fabric), jitter=0.03, noise=0.06),
        "sheet": Paint(_pick(rng, [(236, 234, 228), (200, 210, 226), (226, 210, 200)]), jitter=0.02, noise=0.05),
        "blanket": Paint(_pick(rng, [(90, 110, 150), (170, 90, 80), (120, 140, 110)]), jitter=0.03, noise=0.08,
                         stripes=0.18, stripe_rgb=(200, 200, 190)),
        "pillow": Paint((245, 244, 238), jitter=0.02, noise=0.04),
        "glass": Paint((150, 185, 205), jitter=0.01, noise=0.03),
        "frame": Paint((245, 245, 245), jitter=0.01, noise=0.02),
        "door": Paint(_pick(rng, [(240, 238, 232), (140, 96, 60), (200, 180, 150)]), jitter=0.015, noise=0.04),
        "screen": Paint((22, 24, 30), jitter=0.01, noise=0.05),
        "light": Paint((252, 248, 232), jitter=0.005, noise=0.01),
        "shade": Paint((240, 226, 190), jitter=0.01, noise=0.03),
        "curtain": Paint(_pick(rng, [(200, 190, 170), (120, 130, 150), (170, 120, 110), (225, 222, 210)]),
                         jitter=0.04, noise=0.08),
        "rug": Paint(_pick(rng, [(150, 50, 45), (60, 80, 130), (190, 170, 130)]), jitter=0.05, noise=0.06,
                     stripes=0.25, stripe_rgb=(_pick(rng, [(220, 210, 180), (40, 40, 50), (120, 30, 30)]))),
        "leaf": Paint((60, 120, 55), jitter=0.12, noise=0.15),
        "pot": Paint((170, 95, 60), jitter=0.03, noise=0.05),
        "cabinet": Paint(_pick(rng, [(235, 235, 230), wood, (90, 100, 110)]), jitter=0.02, noise=0.05),
        "handle": Paint((180, 180, 185), jitter=0.01, noise=0.02),
    }


# -------------------------------------------------------------------------------------------------
# Furniture (local frame: origin at the footprint centre on the floor, front = +y, up = +z)
# -------------------------------------------------------------------------------------------------
def _table(mb, pt, tf, w, d, h, leg=0.05, cls="table"):
    o = mb.new_object(cls)
    mb.box(o, pt["wood"], (0, 0, h - 0.02), (w, d, 0.04), tf, cell=0.2)
    for sx in (-1, 1):
        for sy in (-1, 1):
            mb.box(o, pt["wood"], (sx * (w / 2 - 0.06), sy * (d / 2 - 0.06), (h - 0.04) / 2), (leg, leg, h - 0.04),
                   tf, omit=("-z", "+z"), cell=0.2)


def _chair(mb, tf, paint):
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


def _sofa(mb, pt, tf, w, d=0.9):
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


def _bed(mb, pt, tf, w, L):
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


def _cabinet(mb, pt, tf, w, d, h, cls="cabinet", doors=2):
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


def _tv(mb, pt, tf, w, z0):
    o = mb.new_object("tv-screen")
    h = w * 0.58
    mb.box(o, pt["metal"], (0, 0, z0 + 0.01), (0.32, 0.2, 0.02), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["metal"], (0, 0, z0 + 0.07), (0.06, 0.03, 0.1), tf, omit=("-z",), cell=0.2)
    mb.box(o, pt["screen"], (0, 0.0, z0 + 0.12 + h / 2), (w, 0.05, h), tf, cell=0.2)


def _floor_lamp(mb, pt, tf):
    o = mb.new_object("lamp")
    mb.cylinder(o, pt["metal"], (0, 0), 0.0, 0.03, 0.15, n=12, tf=tf)
    mb.cylinder(o, pt["metal"], (0, 0), 0.03, 1.38, 0.015, n=8, top=False, tf=tf)
    mb.cylinder(o, pt["shade"], (0, 0), 1.38, 1.66, 0.21, n=16, top=True, radius_top=0.15, tf=tf)


def _table_lamp(mb, pt, tf, z0):
    o = mb.new_object("lamp")
    mb.cylinder(o, pt["pot"], (0, 0), z0, z0 + 0.25, 0.06, n=12, top=False, tf=tf)
    mb.cylinder(o, pt["shade"], (0, 0), z0 + 0.25, z0 + 0.45, 0.15, n=16, top=True, radius_top=0.1, tf=tf)


def _plant(mb, pt, tf, rng):
    o = mb.new_object("plant")
    r = rng.uniform(0.14, 0.19)
    hp = rng.uniform(0.3, 0.42)
    mb.cylinder(o, pt["pot"], (0, 0), 0.0, hp, r, n=12, top=True, radius_top=r * 1.15, tf=tf)
    mb.cylinder(o, pt["wood"], (0, 0), hp, hp + 0.35, 0.015, n=8, top=False, tf=tf)
    for k in range(3):
        c = (rng.uniform(-0.06, 0.06), rng.uniform(-0.06, 0.06), hp + 0.35 + 0.22 * k)
        rr = rng.uniform(0.18, 0.27) * (1.0 - 0.2 * k)
        mb.blob(o, pt["leaf"], c, (rr, rr, rr * 0.9), n=4, bumpiness=0.25, tf=tf)


def _bookshelf(mb, pt, tf, rng, w, h=1.8, d=0.32):
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


def _rug(mb, pt, tf, w, d):
    o = mb.new_object("rug")
    mb.box(o, pt["rug"], (0, 0, 0.005), (w, d, 0.01), tf, omit=("-z",), cell=0.12)


# -------------------------------------------------------------------------------------------------
# The house
# -------------------------------------------------------------------------------------------------
class _House:
    def __init__(self, rng: np.random.Generator, n_rooms: int):
        self.rng = rng
        self.mb = MeshBuilder(rng)
        self.pt = _paints(rng)
        self.hc = float(rng.uniform(2.5, 2.8))
        self.rooms: list[Room] = []
        self.obstacles: list[tuple[float, float, float, float]] = []  # 2-D boxes the camera must avoid
        self.keepout: dict[int, list] = {}
        self.rugs: dict[int, list] = {}
        self._layout(n_rooms)

    # ---- layout ---------------------------------------------------------------------------------
    def _layout(self, k: int) -> None:
        rng = self.rng
        nr, nc = (1, k) if k <= 3 else (2, 2) if k == 4 else (2, 3)
        scale = 1.25 if k == 1 else 1.0
        widths = rng.uniform(3.5, 5.0, nc) * scale
        depths = rng.uniform(3.6, 4.8, nr) * scale
        xs = np.concatenate([[0.0], np.cumsum(widths + WALL_T)])
        ys = np.concatenate([[0.0], np.cumsum(depths + WALL_T)])
        cells = []
        for r in range(nr):
            cols = range(nc) if r % 2 == 0 else range(nc - 1, -1, -1)
            cells += [(r, c) for c in cols]
        cells = cells[:k]
        kinds = {1: ["studio"], 2: ["living", "bedroom"], 3: ["living", "bedroom", "dining"]}.get(
            k, ["living", "bedroom", "dining", "bedroom", "office", "bedroom"][:k])
        where = {}
        for i, (r, c) in enumerate(cells):
            self.rooms.append(Room(i, kinds[i], xs[c], xs[c] + widths[c], ys[r], ys[r] + depths[r]))
            where[(r, c)] = i
        for (r, c), i in where.items():
            for side, (dr, dc) in {"E": (0, 1), "W": (0, -1), "N": (1, 0), "S": (-1, 0)}.items():
                j = where.get((r + dr, c + dc))
                if j is not None:
                    self.rooms[i].shared[side] = j
        # Interior doors between rooms that follow each other.
        for i in range(k - 1):
            a, b = self.rooms[i], self.rooms[i + 1]
            side = next(s for s, j in a.shared.items() if j == i + 1)
            lo, hi = a.side_range(side)
            w = rng.uniform(0.92, 1.0)
            s0 = rng.uniform(lo + 0.35, hi - 0.35 - w)
            zt = rng.uniform(2.05, 2.12)
            leaf_in_a = bool(rng.integers(2))
            hinge = bool(rng.integers(2))
            a.openings.append(Opening("door", side, s0, s0 + w, 0.0, zt, other=i + 1, owner=True,
                                      leaf_here=leaf_in_a, hinge_s0=hinge))
            b.openings.append(Opening("door", _OPPOSITE[side], s0, s0 + w, 0.0, zt, other=i, owner=False,
                                      leaf_here=not leaf_in_a, hinge_s0=hinge))
        # Entrance door in the first room, windows in every room's exterior walls.
        for room in self.rooms:
            ext = [s for s in "SNWE" if s not in room.shared]
            rng.shuffle(ext)
            ext.sort(key=lambda s: -(room.side_range(s)[1] - room.side_range(s)[0]))
            if room.idx == 0 and ext:
                side = ext[-1] if len(ext) > 1 else ext[0]
                if not self._add_opening(room, side, "entrance", rng.uniform(0.9, 1.0), 0.0, 2.1):
                    raise _Retry
            n_win = 0
            for j, side in enumerate(ext):
                if n_win >= 2 or (j > 0 and rng.random() < 0.7):
                    continue
                for _ in range(1 if rng.random() < 0.8 else 2):
                    w = rng.uniform(0.9, 1.5)
                    z0 = rng.uniform(0.9, 1.0)
                    z1 = min(self.hc - 0.3, rng.uniform(2.05, 2.25))
                    n_win += self._add_opening(room, side, "window", w, z0, z1)
            if n_win == 0:
                raise _Retry
        self._set_keepouts()

    def _set_keepouts(self) -> None:
        """Per room, the boxes in front of its doors and windows that furniture keeps out of, and the curtains as obstacles."""
        for room in self.rooms:
            ko = []  # (box, tallest item allowed there)
            for op in room.openings:
                if op.kind in ("door", "entrance"):
                    ko.append((room.aabb(op.side, op.s0 - 0.35, op.s1 + 0.35, -1.25, 0.0), -1.0))
                else:
                    ko.append((room.aabb(op.side, op.s0 - 0.1, op.s1 + 0.1, -0.4, 0.0), op.z0 - 0.03))
                    for a, b in self._curtain_spans(room, op):
                        self.obstacles.append(room.aabb(op.side, a, b, -0.16, 0.0))
            self.keepout[room.idx] = ko

    def _curtain_spans(self, room: Room, o: Opening) -> list[tuple[float, float]]:
        lo, hi = room.side_range(o.side)
        return [(max(lo + 0.02, o.s0 - 0.35), o.s0 + 0.15), (o.s1 - 0.15, min(hi - 0.02, o.s1 + 0.35))]

    def _add_opening(self, room: Room, side: str, kind: str, w: float, z0: float, z1: float) -> bool:
        lo, hi = room.side_range(side)
        margin = 0.6 if kind == "window" else 0.4
        if hi - lo < w + 2 * margin:
            return False
        for _ in range(20):
            s0 = self.rng.uniform(lo + margin, hi - margin - w)
            if all(o.side != side or s0 > o.s1 + 0.9 or s0 + w < o.s0 - 0.9 for o in room.openings):
                room.openings.append(Opening(kind, side, s0, s0 + w, z0, z1))
                return True
        return False

    # ---- placement ------------------------------------------------------------------------------
    def _free(self, room: Room, box, gap=0.05, height=3.0) -> bool:
        if box[0] < room.x0 + 0.01 or box[1] > room.x1 - 0.01 or box[2] < room.y0 + 0.01 or box[3] > room.y1 - 0.01:
            return False
        if any(_overlap(box, k) and height > hmax for k, hmax in self.keepout[room.idx]):
            return False
        return not any(_overlap(box, b, gap) for b in self.obstacles)

    def _on_wall(self, room: Room, w, d, height=3.0, sides=None, tries=80, near=None, gap=0.03, corner=False):
        """Find a wall spot for a w x d footprint (back to the wall). Returns (Transform2D, box) or None."""
        rng = self.rng
        sides = list(sides) if sides is not None else ["S", "N", "W", "E"]
        for t in range(tries):
            side = sides[int(rng.integers(len(sides)))]
            lo, hi = room.side_range(side)
            if hi - lo < w + 0.04:
                continue
            if corner:
                s = lo + w / 2 + 0.02 if rng.random() < 0.5 else hi - w / 2 - 0.02
            elif near is not None and t < tries // 2:
                s = float(np.clip(near + rng.normal(0, 0.3), lo + w / 2 + 0.02, hi - w / 2 - 0.02))
            else:
                s = rng.uniform(lo + w / 2 + 0.02, hi - w / 2 - 0.02)
            box = room.aabb(side, s - w / 2, s + w / 2, -(gap + d), -gap)
            if self._free(room, box, height=height):
                n = _NORMAL[side]
                c = room.P(side, s, -(gap + d / 2), 0.0)
                return Transform2D(c[0], c[1], float(np.arctan2(-n[0], n[1]))), box, side, s
        return None

    def _local_box(self, tf: Transform2D, cx, cy, w, d):
        c = tf.point([cx, cy, 0.0])
        half = np.abs(tf.R[:2, :2]) @ np.array([w / 2, d / 2])
        return (c[0] - half[0], c[0] + half[0], c[1] - half[1], c[1] + half[1])

    def _dining_set(self, room: Room, small=False) -> bool:
        rng = self.rng
        w = rng.uniform(1.0, 1.2) if small else rng.uniform(1.4, 1.8)
        d = rng.uniform(0.75, 0.85) if small else rng.uniform(0.85, 0.95)
        long_x = (room.x1 - room.x0) >= (room.y1 - room.y0)
        for _ in range(40):
            c = room.center + rng.uniform(-0.6, 0.6, 2) * (1.6 if small else 1.0)
            tf = Transform2D(c[0], c[1], 0.0 if long_x else np.pi / 2)
            n_side = 1 if w < 1.5 else 2
            seats = [((k - (n_side - 1) / 2) * (w / n_side), sy) for k in range(n_side) for sy in (-1, 1)]
            chairs = []
            for x, sy in seats:
                cy = sy * (d / 2 + 0.14)
                chairs.append((Transform2D(*tf.point([x, cy, 0.0])[:2], tf_yaw(tf) + (0.0 if sy < 0 else np.pi)),
                               self._local_box(tf, x, cy, 0.46, 0.46)))
            table_box = self._local_box(tf, 0, 0, w, d)
            boxes = [table_box] + [b for _, b in chairs]
            if not all(self._free(room, b, gap=0.3) for b in boxes):
                continue
            if not small and rng.random() < 0.6:
                self._add_rug(room, tf, w + 1.2, d + 1.3)
            _table(self.mb, self.pt, tf, w, d, 0.75)
            paint = _pick(rng, [self.pt["wood"], self.pt["metal"], self.pt["white"]])
            for ctf, _ in chairs:
                _chair(self.mb, ctf, paint)
            self.obstacles += boxes
            return True
        return False

    def _add_rug(self, room: Room, tf: Transform2D, w, d) -> None:
        box = self._local_box(tf, 0, 0, w, d)
        if (box[0] < room.x0 + 0.1 or box[1] > room.x1 - 0.1 or box[2] < room.y0 + 0.1 or box[3] > room.y1 - 0.1
                or any(_overlap(box, r) for r in self.rugs.get(room.idx, []))):
            return
        self.rugs.setdefault(room.idx, []).append(box)
        _rug(self.mb, self.pt, Transform2D((box[0] + box[1]) / 2, (box[2] + box[3]) / 2), box[1] - box[0],
             box[3] - box[2])

    def _living(self, room: Room) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        w = rng.uniform(1.8, 2.3)
        spot = self._on_wall(room, w, 0.9, height=0.86)
        if spot is None:
            raise _Retry
        tf, box, side, s = spot
        _sofa(mb, pt, tf, w)
        self.obstacles.append(box)
        ctw, ctd = rng.uniform(0.9, 1.2), rng.uniform(0.5, 0.6)
        cty = 0.45 + 0.45 + ctd / 2
        cbox = self._local_box(tf, 0, cty, ctw, ctd)
        if self._free(room, cbox, gap=0.2):
            rug_tf = Transform2D(*tf.point([0, cty - 0.1, 0])[:2], tf_yaw(tf))
            self._add_rug(room, rug_tf, min(w + 0.4, 2.4), 1.6)
            _table(mb, pt, Transform2D(*tf.point([0, cty, 0])[:2], tf_yaw(tf)), ctw, ctd, 0.42, leg=0.045)
            self.obstacles.append(cbox)
        lamp_x = (w / 2 + 0.3) * (1 if rng.random() < 0.5 else -1)
        lbox = self._local_box(tf, lamp_x, -0.2, 0.42, 0.42)
        if self._free(room, lbox):
            _floor_lamp(mb, pt, Transform2D(*tf.point([lamp_x, -0.2, 0])[:2]))
            self.obstacles.append(lbox)
        tvw = rng.uniform(1.0, 1.4)
        spot = self._on_wall(room, tvw + 0.3, 0.45, sides=[_OPPOSITE[side]], near=s) or self._on_wall(
            room, tvw + 0.3, 0.45)
        if spot is None:
            raise _Retry
        ttf, tbox, _, _ = spot
        _cabinet(mb, pt, ttf, tvw + 0.3, 0.45, 0.5, doors=3)
        _tv(mb, pt, Transform2D(*ttf.point([0, 0.0, 0])[:2], tf_yaw(ttf)), tvw, 0.5)
        self.obstacles.append(tbox)
        self._extras(room, plants=1 + int(rng.random() < 0.5), shelf=rng.random() < 0.7)

    def _bedroom(self, room: Room, desk: bool = True) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        bw, bl = _pick(rng, [1.4, 1.6, 1.8]), rng.uniform(2.0, 2.1)
        stands = True
        spot = self._on_wall(room, bw + 1.0, bl, height=1.04)
        if spot is None:
            stands = False
            spot = self._on_wall(room, bw, bl, height=1.04)
        if spot is None:
            raise _Retry
        tf, box, side, s = spot
        _bed(mb, pt, tf, bw, bl)
        self.obstacles.append(self._local_box(tf, 0, 0, bw, bl))
        for sx in ((-1, 1) if stands else ()):
            x = sx * (bw / 2 + 0.27)
            ns = Transform2D(*tf.point([x, -bl / 2 + 0.2, 0])[:2], tf_yaw(tf))
            _cabinet(mb, pt, ns, 0.45, 0.4, 0.55, cls="nightstand", doors=1)
            _table_lamp(mb, pt, ns, 0.55)
            self.obstacles.append(self._local_box(ns, 0, 0, 0.45, 0.4))
        if rng.random() < 0.6:
            self._add_rug(room, Transform2D(*tf.point([0, bl / 2 + 0.1, 0])[:2], tf_yaw(tf)), bw + 0.6, 1.0)
        ww = rng.uniform(1.0, 1.6)
        spot = self._on_wall(room, ww, 0.6)
        if spot is not None:
            wtf, wbox, _, _ = spot
            _cabinet(mb, pt, wtf, ww, 0.6, 2.0)
            self.obstacles.append(wbox)
        if desk:
            self._desk(room)
        self._extras(room, plants=int(rng.random() < 0.6), shelf=False)

    def _desk(self, room: Room) -> bool:
        rng = self.rng
        dw = rng.uniform(1.0, 1.3)
        spot = self._on_wall(room, dw, 1.25, height=0.9)
        if spot is None:
            return False
        tf, box, _, _ = spot
        _table(self.mb, self.pt, Transform2D(*tf.point([0, -0.6 + 0.3, 0])[:2], tf_yaw(tf)), dw, 0.6, 0.74)
        _chair(self.mb, Transform2D(*tf.point([0, 0.25, 0])[:2], tf_yaw(tf) + np.pi), self.pt["metal"])
        self.obstacles.append(box)
        return True

    def _dining(self, room: Room) -> None:
        if not self._dining_set(room):
            raise _Retry
        sw = self.rng.uniform(1.2, 1.8)
        spot = self._on_wall(room, sw, 0.45, height=0.85)
        if spot is not None:
            tf, box, _, _ = spot
            _cabinet(self.mb, self.pt, tf, sw, 0.45, 0.85, doors=3)
            self.obstacles.append(box)
        self._extras(room, plants=1 + int(self.rng.random() < 0.5), shelf=False)

    def _extras(self, room: Room, plants: int, shelf: bool) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        for _ in range(plants):
            spot = self._on_wall(room, 0.6, 0.6, corner=True)
            if spot is not None:
                tf, box, _, _ = spot
                _plant(mb, pt, Transform2D(*tf.point([0, 0, 0])[:2]), rng)
                self.obstacles.append(box)
        if shelf:
            bw = rng.uniform(0.8, 1.2)
            spot = self._on_wall(room, bw, 0.32)
            if spot is not None:
                tf, box, _, _ = spot
                _bookshelf(mb, pt, tf, rng, bw)
                self.obstacles.append(box)

    def furnish(self) -> None:
        for room in self.rooms:
            if room.kind == "living":
                self._living(room)
                if not any(r.kind == "dining" for r in self.rooms) and not self._dining_set(room, small=True):
                    raise _Retry
            elif room.kind == "bedroom":
                self._bedroom(room)
            elif room.kind == "dining":
                self._dining(room)
            elif room.kind == "office":
                if not self._desk(room):
                    raise _Retry
                self._extras(room, plants=1, shelf=True)
            else:  # studio
                self._bedroom(room, desk=False)
                self._living(room)
                if not self._dining_set(room, small=True):
                    raise _Retry

    # ---- shell: floors, ceilings, walls, openings ----------------------------------------------
    def build_shell(self) -> None:
        mb, pt, hc = self.mb, self.pt, self.hc
        for room in self.rooms:
            self._floor(room)
            ceil = mb.new_object("ceiling", tint=0.02)
            xs = np.linspace(room.x0, room.x1, int(np.ceil((room.x1 - room.x0) / 0.5)) + 1) - room.x0
            ys = np.linspace(room.y0, room.y1, int(np.ceil((room.y1 - room.y0) / 0.5)) + 1) - room.y0
            mb.grid(ceil, pt["ceiling"], (room.x0, room.y0, hc), (1, 0, 0), (0, 1, 0), xs, ys, (0, 0, -1))
            nl = 2 if max(room.x1 - room.x0, room.y1 - room.y0) > 4.6 else 1
            for k in range(nl):
                f = (k + 0.5) / nl
                c = (room.x0 + f * (room.x1 - room.x0), room.center[1]) if room.x1 - room.x0 >= room.y1 - room.y0 \
                    else (room.center[0], room.y0 + f * (room.y1 - room.y0))
                lo = mb.new_object("lamp")
                mb.cylinder(lo, pt["light"], c, hc - 0.09, hc, self.rng.uniform(0.18, 0.28), n=16, top=False,
                            bottom=True)
            for side in "SNWE":
                self._wall(room, side)

    def _floor(self, room: Room) -> None:
        mb, rng = self.mb, self.rng
        fl = mb.new_object("floor", tint=0.02)
        holes = self.rugs.get(room.idx, [])
        plank_w, plank_l = 0.2, rng.uniform(0.9, 1.4)
        ys = np.concatenate([np.arange(room.y0, room.y1, plank_w), [room.y1]] + [[h[2], h[3]] for h in holes])
        ys = np.unique(np.round(ys, 9))
        quads = []
        for ya, yb in zip(ys[:-1], ys[1:]):
            row = int(np.floor((ya - room.y0) / plank_w + 1e-9))
            off = (row * 0.37 % 1.0) * plank_l
            xs = np.concatenate([[room.x0, room.x1], np.arange(room.x0 - off, room.x1, plank_l)[1:]]
                                + [[h[0], h[1]] for h in holes])
            xs = np.unique(np.round(np.clip(xs, room.x0, room.x1), 9))
            for xa, xb in zip(xs[:-1], xs[1:]):
                cx, cy = (xa + xb) / 2, (ya + yb) / 2
                if any(h[0] < cx < h[1] and h[2] < cy < h[3] for h in holes):
                    continue
                quads.append([(xa, ya, 0), (xb, ya, 0), (xb, yb, 0), (xa, yb, 0)])
        # One quad per plank piece; pieces of one plank get different jitter, which reads as wear.
        mb.quads(fl, self.pt["floor"], np.array(quads, dtype=np.float64))

    def _wall(self, room: Room, side: str) -> None:
        mb, pt, hc = self.mb, self.pt, self.hc
        wo = mb.new_object("wall", tint=0.015)
        lo, hi = room.side_range(side)
        ops = [o for o in room.openings if o.side == side]
        su = np.concatenate([np.linspace(lo, hi, int(np.ceil((hi - lo) / 0.4)) + 1)] + [[o.s0, o.s1] for o in ops])
        sv = np.concatenate([np.linspace(0, hc, int(np.ceil(hc / 0.4)) + 1)] + [[o.z0, o.z1] for o in ops])
        n3 = np.array([*_NORMAL[side], 0.0])
        U = np.array([1.0, 0, 0]) if side in "SN" else np.array([0, 1.0, 0])

        def skip(sa, sb, ta, tb):  # cells of the wall's grid (offsets from ``lo``) inside an opening
            sc, tc = lo + (sa + sb) / 2, (ta + tb) / 2
            out = np.zeros(len(sa), bool)
            for o in ops:
                out |= (sc > o.s0) & (sc < o.s1) & (tc > o.z0) & (tc < o.z1)
            return out

        origin = room.P(side, lo, 0.0, 0.0)
        mb.grid(wo, pt["wall"], origin, U, (0, 0, 1), su - lo, sv, n3, skip=skip)
        for o in ops:
            self._opening(room, o, wo, U, n3)

    def _opening(self, room: Room, o: Opening, wo: int, U: np.ndarray, n3: np.ndarray) -> None:
        mb, pt = self.mb, self.pt
        out = -n3  # outward
        if o.kind == "window":
            depth = WALL_T / 2
        elif o.kind == "entrance":
            depth = WALL_T / 2 - 0.02
        else:
            depth = WALL_T if o.owner else 0.0
        w, h = o.s1 - o.s0, o.z1 - o.z0
        if depth > 0:
            z = np.array([0, 0, 1.0])
            mb.rect(wo, pt["wall"], room.P(o.side, o.s0, 0, o.z0), out, z, depth, h, U, cell=0.4)
            mb.rect(wo, pt["wall"], room.P(o.side, o.s1, 0, o.z0), out, z, depth, h, -U, cell=0.4)
            mb.rect(wo, pt["wall"], room.P(o.side, o.s0, 0, o.z1), U, out, w, depth, -z, cell=0.4)
            if o.kind == "window":
                mb.rect(wo, pt["white"], room.P(o.side, o.s0, 0, o.z0), U, out, w, depth, z, cell=0.4)
            else:
                fl = mb.new_object("floor", tint=0.02)
                mb.rect(fl, pt["floor"], room.P(o.side, o.s0, 0, 0), U, out, w, depth, z, cell=0.4)
        if o.kind == "window":
            win = mb.new_object("window")
            mb.rect(win, pt["glass"], room.P(o.side, o.s0, depth, o.z0), U, np.array([0, 0, 1.0]), w, h, n3, cell=0.5)
            bars = [(o.s0, o.s0 + 0.05, o.z0, o.z1), (o.s1 - 0.05, o.s1, o.z0, o.z1),
                    (o.s0, o.s1, o.z0, o.z0 + 0.05), (o.s0, o.s1, o.z1 - 0.05, o.z1)]
            if w > 1.2:
                m = (o.s0 + o.s1) / 2
                bars.append((m - 0.025, m + 0.025, o.z0, o.z1))
            for s0, s1, z0, z1 in bars:
                a = room.P(o.side, s0, depth - 0.03, z0)
                b = room.P(o.side, s1, depth + 0.03, z1)
                mb.box(win, pt["frame"], (a + b) / 2, np.abs(b - a), cell=0.4)
            self._curtains(room, o)
        elif o.kind == "entrance":
            d = mb.new_object("door")
            a = room.P(o.side, o.s0, depth, 0.0)
            b = room.P(o.side, o.s1, depth + 0.04, o.z1)
            mb.box(d, pt["door"], (a + b) / 2, np.abs(b - a), omit=(), cell=0.3)
            hs = o.s0 + 0.08 if o.hinge_s0 else o.s1 - 0.08
            hp = room.P(o.side, hs, depth - 0.03, 1.0)
            mb.box(d, pt["handle"], hp, np.abs(room.P(o.side, 0.12, 0.06, 0.03) - room.P(o.side, 0, 0, 0)), cell=0.3)
        elif o.leaf_here:
            d = mb.new_object("door")
            lw = w - 0.02
            s0 = o.s0 + 0.005 if o.hinge_s0 else o.s1 - 0.045
            a = room.P(o.side, s0, -0.01, 0.005)
            b = room.P(o.side, s0 + 0.04, -0.01 - lw, o.z1 - 0.01)
            mb.box(d, pt["door"], (a + b) / 2, np.abs(b - a), omit=("-z",), cell=0.3)
            self.obstacles.append(room.aabb(o.side, s0, s0 + 0.04, -0.01 - lw, -0.01))

    def _curtains(self, room: Room, o: Opening) -> None:
        mb = self.mb
        c = mb.new_object("curtain")
        top = min(self.hc - 0.05, o.z1 + 0.15)
        n3 = np.array([*_NORMAL[o.side], 0.0])
        for a, b in self._curtain_spans(room, o):
            n = max(2, int(round((b - a) / 0.08)))
            s = np.linspace(a, b, n + 1)
            off = np.where(np.arange(n + 1) % 2 == 0, -0.08, -0.15)
            zs = np.linspace(0.03, top, 5)
            quads = []
            for k in range(n):
                for j in range(len(zs) - 1):
                    p = [room.P(o.side, s[k], off[k], zs[j]), room.P(o.side, s[k + 1], off[k + 1], zs[j]),
                         room.P(o.side, s[k + 1], off[k + 1], zs[j + 1]), room.P(o.side, s[k], off[k], zs[j + 1])]
                    if np.dot(np.cross(p[1] - p[0], p[3] - p[0]), n3) < 0:
                        p = p[::-1]
                    quads.append(p)
            mb.quads(c, self.pt["curtain"], np.array(quads))


def tf_yaw(tf: Transform2D) -> float:
    return float(np.arctan2(tf.R[1, 0], tf.R[0, 0]))


# -------------------------------------------------------------------------------------------------
# Trajectory
# -------------------------------------------------------------------------------------------------
def _clearance_map(house: _House):
    """Conservative 2-D clearance (metres) to walls and obstacles on a RASTER grid; returns (dist, lo)."""
    from scipy import ndimage

    rooms = house.rooms
    lo = np.array([min(r.x0 for r in rooms) - 0.5, min(r.y0 for r in rooms) - 0.5])
    hi = np.array([max(r.x1 for r in rooms) + 0.5, max(r.y1 for r in rooms) + 0.5])
    n = np.ceil((hi - lo) / RASTER).astype(int)
    cx = lo[0] + (np.arange(n[0]) + 0.5) * RASTER
    cy = lo[1] + (np.arange(n[1]) + 0.5) * RASTER
    free = np.zeros(n, bool)

    def cells(box, grow):
        ix = (cx > box[0] - grow) & (cx < box[1] + grow)
        iy = (cy > box[2] - grow) & (cy < box[3] + grow)
        return np.ix_(ix, iy)

    for r in rooms:
        free[cells((r.x0, r.x1, r.y0, r.y1), -RASTER / 2)] = True
        for o in r.openings:
            if o.kind == "door" and o.owner:
                free[cells(r.aabb(o.side, o.s0, o.s1, -0.1, WALL_T + 0.1), -RASTER / 2)] = True
    for b in house.obstacles:
        free[cells(b, RASTER / 2)] = False
    dist = (ndimage.distance_transform_edt(free) - 0.71) * RASTER
    return np.where(free, dist, -1.0), lo


def _sample(dist, lo, pts):
    """Bilinear lookup of the clearance map at world points (n, 2)."""
    from scipy import ndimage

    ij = (np.asarray(pts) - lo) / RASTER - 0.5
    return ndimage.map_coordinates(dist, ij.T, order=1, mode="nearest")


def _plan(house: _House, frames: int, rng: np.random.Generator) -> np.ndarray:
    """The trajectory of a snake-order home: every room in turn, through the door to the next."""
    return _route(house, frames, rng, _snake_tour)


def _snake_tour(house: _House, centers: np.ndarray, views, snap) -> list[int]:
    """Waypoints (raster node ids): per room two wide-open viewpoints (one in each half), then the approaches
    on both sides of the door to the next room."""
    way: list[int] = []
    rooms = house.rooms
    for i, r in enumerate(rooms):
        v = views(r)
        entry = way[-1] if way else None
        exit_door = next((o for o in r.openings if o.kind == "door" and o.other == i + 1), None)
        if entry is not None:
            v.sort(key=lambda k: np.linalg.norm(centers[k] - centers[entry]))
        elif exit_door is not None:
            m = r.P(exit_door.side, (exit_door.s0 + exit_door.s1) / 2, 0.0, 0.0)[:2]
            v.sort(key=lambda k: -np.linalg.norm(centers[k] - m))
        way += v
        if exit_door is not None:
            m = (exit_door.s0 + exit_door.s1) / 2
            nxt = rooms[i + 1]
            way.append(snap(r.P(exit_door.side, m, -0.6, 0.0)[:2], r))
            way.append(snap(r.P(exit_door.side, m, WALL_T + 0.6, 0.0)[:2], nxt))
    return way


def _route(house: _House, frames: int, rng: np.random.Generator, tour) -> np.ndarray:
    """``frames`` poses along the clearance-weighted shortest path through the waypoints ``tour`` gives.

    ``tour(house, centers, views, snap)`` returns raster node ids; ``views(room)`` gives a room's two
    wide-open viewpoints, ``snap(xy, room)`` the free node nearest a point (inside ``room`` when given).
    """
    from scipy import ndimage, sparse
    from scipy.sparse import csgraph

    dist, lo = _clearance_map(house)
    ok = dist >= PLAN_CLEARANCE
    nx, ny = ok.shape
    ids = -np.ones(ok.shape, np.int64)
    ids[ok] = np.arange(ok.sum())
    rows, cols, wts = [], [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        sa = (slice(max(0, -dx), nx - max(0, dx)), slice(max(0, -dy), ny - max(0, dy)))
        sb = (slice(max(0, dx), nx - max(0, -dx)), slice(max(0, dy), ny - max(0, -dy)))
        m = ok[sa] & ok[sb]
        da = np.minimum(dist[sa], dist[sb])[m]
        rows.append(ids[sa][m])
        cols.append(ids[sb][m])
        wts.append(RASTER * np.hypot(dx, dy) * (1.0 + 0.15 / np.maximum(da, 0.05)))
    g = sparse.coo_matrix((np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(int(ok.sum()),) * 2).tocsr()
    ci, cj = np.nonzero(ok)
    centers = lo + (np.stack([ci, cj], 1) + 0.5) * RASTER

    def snap(p, room: Room | None = None):
        d = np.linalg.norm(centers - p, axis=1)
        if room is not None:
            inside = ((centers[:, 0] > room.x0) & (centers[:, 0] < room.x1) & (centers[:, 1] > room.y0)
                      & (centers[:, 1] < room.y1))
            d = np.where(inside, d, np.inf)
        k = int(np.argmin(d))
        if d[k] > 0.35:
            raise _Retry
        return k

    dist_ok = np.where(ok, dist, -1.0)

    def views(r: Room) -> list[int]:
        long_x = (r.x1 - r.x0) >= (r.y1 - r.y0)
        out = []
        for half in (0, 1):
            if long_x:
                xm = (r.x0 + r.x1) / 2
                box = (r.x0, xm, r.y0, r.y1) if half == 0 else (xm, r.x1, r.y0, r.y1)
            else:
                ym = (r.y0 + r.y1) / 2
                box = (r.x0, r.x1, r.y0, ym) if half == 0 else (r.x0, r.x1, ym, r.y1)
            inside = ((centers[:, 0] > box[0]) & (centers[:, 0] < box[1]) & (centers[:, 1] > box[2])
                      & (centers[:, 1] < box[3]))
            if not inside.any():
                raise _Retry
            score = np.where(inside, dist_ok[ci, cj], -np.inf)
            out.append(int(np.argmax(score)))
        return out

    way = tour(house, centers, views, snap)
    path = [centers[way[0]]]
    for a, b in zip(way[:-1], way[1:]):
        if a == b:
            continue
        _, pred = csgraph.dijkstra(g, directed=False, indices=a, return_predecessors=True)
        if pred[b] < 0:
            raise _Retry
        seg = [b]
        while seg[-1] != a:
            seg.append(int(pred[seg[-1]]))
        path += [centers[k] for k in seg[::-1][1:]]
    path = np.array(path)
    # Resample densely, smooth while clearance allows, then take `frames` poses by arc length.
    dense = _resample(path, max(2, int(_length(path) / 0.05)))
    for sigma in (8.0, 5.0, 3.0, 1.5, 0.0):
        sm = ndimage.gaussian_filter1d(dense, sigma, axis=0, mode="nearest") if sigma else dense
        if _sample(dist, lo, sm).min() >= CLEARANCE:
            break
    else:
        raise _Retry
    xy = _resample(sm, frames)
    return _orient(xy, sm, rng)


def _length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _resample(p: np.ndarray, n: int) -> np.ndarray:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, p[:, k]) for k in range(p.shape[1])], axis=1)


def _orient(xy: np.ndarray, dense: np.ndarray, rng) -> np.ndarray:
    from scipy import ndimage

    n = len(xy)
    u = np.linspace(0.0, 1.0, n)
    L = _length(dense)
    cyc = max(1.0, L / 6.0)
    ph = rng.uniform(0, 2 * np.pi, 5)
    z = 1.45 + 0.18 * np.sin(2 * np.pi * cyc * u + ph[0])
    pitch = np.deg2rad(4.0) * np.sin(2 * np.pi * cyc * 1.3 * u + ph[1])
    roll = np.deg2rad(2.5) * np.sin(2 * np.pi * cyc * 0.8 * u + ph[2])
    tang = np.gradient(xy, axis=0) if n > 1 else np.array([[1.0, 0.0]])
    yaw = np.unwrap(np.arctan2(tang[:, 1], tang[:, 0]))
    yaw = ndimage.gaussian_filter1d(yaw, 1.5, mode="nearest") + np.deg2rad(25) * np.sin(2 * np.pi * cyc * 0.5 * u + ph[3])
    T = np.empty((n, 4, 4))
    for k in range(n):
        fwd = np.array([np.cos(yaw[k]) * np.cos(pitch[k]), np.sin(yaw[k]) * np.cos(pitch[k]), np.sin(pitch[k])])
        Tk = look_at([xy[k, 0], xy[k, 1], z[k]], fwd)
        c, s = np.cos(roll[k]), np.sin(roll[k])
        Tk[:3, :3] = Tk[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        T[k] = Tk
    return T


# -------------------------------------------------------------------------------------------------
# Entry points
# -------------------------------------------------------------------------------------------------
REQUIRED = tuple(EVAL8) + tuple(OPEN4)


SHIFT_STEP = 0.001  # metres: the seeded offset is a whole number of millimetres (the depth PNG's step)
SHIFT_SPAN = 1.0  # metres: the seeded offset lies in [0, SHIFT_SPAN) on each axis


def lattice_offset(seed: int) -> np.ndarray:
    """The home's seeded offset from the origin: (3,) float64 metres, each axis uniform over the whole
    millimetres of [0, ``SHIFT_SPAN``), drawn from ``np.random.default_rng([seed, SHIFT_STREAM])``.

    No clearance rule: modulo the default 8 cm lattice every millimetre position is equally likely, so
    the floor (laid out at z = 0) lies exactly on a voxel face one scene in 80 and within 3 mm of one
    about one in eleven, as large planes of real scans do. The mapper has to be robust to that.
    """
    rng = np.random.default_rng([seed, SHIFT_STREAM])
    return rng.integers(0, round(SHIFT_SPAN / SHIFT_STEP), size=3) * SHIFT_STEP


def parse_offset(text: str) -> tuple[float, float, float]:
    """``"X,Y,Z"`` (metres, finite) -> a 3-tuple of floats; `PanovoccError` naming the option otherwise."""
    parts = text.split(",")
    try:
        xyz = tuple(float(p) for p in parts)
    except ValueError:
        xyz = ()
    if len(xyz) != 3 or not all(np.isfinite(xyz)) or max(abs(x) for x in xyz) > 1e4:
        raise PanovoccError(f"--offset: expected X,Y,Z in metres (three finite numbers), got {text!r}")
    return xyz


def generate_scene(seed: int = DEFAULT_SEED, rooms: int | None = None, frames: int = 60,
                   offset: tuple[float, float, float] | None = None):
    """Generate a procedural scene and its trajectory (pure, no file I/O).

    ``offset``: (x, y, z) metres by which the home (laid out from the origin) is moved; None draws it
    from the seed (`lattice_offset`). The layout itself does not depend on it.

    Returns
    -------
    dict with ``vertices`` (4F, 3) float64 metres (+Z up), ``quads`` (F, 4) int32, ``face_object`` (F,)
    int32, ``colors`` (4F, 3) uint8, ``object_classes`` list[str] (Replica names, e.g. ``tv-screen``),
    ``T_world_cam`` (frames, 4, 4) float64 (OpenCV axes), ``rooms`` list of (x0, x1, y0, y1) interiors,
    ``floor_z`` float metres (the floor's height = the offset's z), ``offset`` (3,) float64 metres,
    ``ceiling_height`` float metres above the floor.
    """
    if rooms is not None and not 1 <= rooms <= MAX_ROOMS:
        raise PanovoccError(f"--rooms must be between 1 and {MAX_ROOMS}, got {rooms}")
    if frames < 2:
        raise PanovoccError(f"--frames must be at least 2, got {frames}")
    base = np.random.default_rng(seed)
    k = int(base.integers(2, 4)) if rooms is None else rooms
    for attempt in range(60):
        rng = np.random.default_rng([seed, attempt])
        try:
            house = _House(rng, k)
            house.furnish()
            house.build_shell()
            T = _plan(house, frames, rng)
        except _Retry:
            continue
        classes = {canonical_name(c) for c in house.mb.object_classes}
        if not set(REQUIRED) <= classes:
            continue
        v, q, obj, col = house.mb.finish()
        # the home is laid out from (0, 0, 0) and moved by a seeded (or the user's) offset: anywhere
        # relative to the voxel lattice, planes exactly on a face included
        shift = lattice_offset(seed) if offset is None else np.asarray(offset, dtype=np.float64)
        sx, sy, sz = (float(x) for x in shift)
        v = v + np.array([sx, sy, sz])
        T = T.copy()
        T[:, :3, 3] += np.array([sx, sy, sz])
        return {"vertices": v, "quads": q, "face_object": obj, "colors": col,
                "object_classes": list(house.mb.object_classes), "T_world_cam": T,
                "rooms": [(r.x0 + sx, r.x1 + sx, r.y0 + sy, r.y1 + sy) for r in house.rooms],
                "floor_z": float(sz), "offset": np.array([sx, sy, sz]), "ceiling_height": house.hc}
    raise PanovoccError(f"could not lay out a {k}-room scene for seed {seed} (try another seed)")


def run_synth(cfg: SynthConfig) -> dict:
    """Write ``cfg.out`` as a Replica-format scene plus ``traj.txt``; returns a summary dict."""
    from ..io.atomic import atomic_dir, check_output
    from ..io.poses import write_poses
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from .replica import TRAJ_NAME, write_replica_scene

    from dataclasses import replace

    cfg = validate_config(cfg)  # seed, rooms, frames: the ranges declared on SynthConfig
    check_output(cfg.out, "scene", cfg.overwrite)  # as the command line: never replace what synth did not write
    if cfg.house:
        from .house import HOUSE_FRAMES, generate_house

        cfg = replace(cfg, frames=HOUSE_FRAMES if cfg.frames is None else cfg.frames)
        g = generate_house(cfg.seed, cfg.rooms, cfg.frames, cfg.offset)
    else:
        cfg = replace(cfg, frames=60 if cfg.frames is None else cfg.frames)
        g = generate_scene(cfg.seed, cfg.rooms, cfg.frames, cfg.offset)
    with atomic_dir(cfg.out) as tmp:
        write_replica_scene(tmp, g["vertices"], g["quads"], g["face_object"], g["colors"], g["object_classes"])
        write_poses(tmp / TRAJ_NAME, g["T_world_cam"])
        write_run_config(tmp / CONFIG_NAME, cfg)
    xy = g["T_world_cam"][:, :2, 3]
    return {"rooms": len(g["rooms"]) - (1 if cfg.house else 0), "corridor": cfg.house,
            "faces": int(len(g["quads"])), "objects": len(g["object_classes"]),
            "classes": sorted({canonical_name(c) for c in g["object_classes"]}), "frames": len(xy),
            "path_m": _length(xy), "offset": [float(x) for x in g["offset"]]}
