"""Building-scale procedural scenes (``panovocc synth --building``): floors of rooms off a corridor, a staircase.

The floor plate is drawn once and shared by every floor: a corridor (1.5-1.8 m wide) along x with a row of
rooms on each side (3.4-4.6 m wide, 3.8-4.6 m deep), and at the west end of the south row a stair shaft
running through all floors. Each floor is drawn on its own (room kinds, doors, windows, furniture, paints)
and built by :class:`~panovocc_cli.datasets.rooms.Home` like the house's rooms: every room has its door
onto the corridor (leaf swung into the room) and windows in its exterior walls; the ground floor has the
entrance at the corridor's west end. Floors are a storey ``H`` apart (ceiling height plus a slab).

The staircase is a dog-leg (U-shaped) stair of real steps: from each floor's landing (1.8 m deep, by the
shaft's door onto the corridor) a flight rises east along the shaft's outer wall to a half landing, the
second flight rises west along the corridor wall to the next floor's landing. Risers of 16-18 cm
(an even number a storey), treads by Blondel's rule (2 risers + 1 tread = 63 cm), flights 1.7-2.1 m wide
with a 40 cm well between them; the flights are solids (treads, risers, sides, a sloped soffit from landing
to landing), balustrades (``handrail``) line the well, the landings' slab edges close the shaft. Steps,
half landings and soffits are ``stair``; the floor landings are ``floor``, their undersides ``ceiling``.

The trajectory is one walk through the whole building: in at the entrance, along the ground floor's
corridor into every room (through its door, to its two viewpoints, back out: the house's tour), to the
stair, up both flights to the next floor (the camera rides at its usual height above the steps, so it
rises along the flights), round that floor, and so on to the top floor. Each floor's part is the house's
clearance-weighted shortest path, smoothed while clearance allows; poses are spaced ``BUILDING_STEP``
apart along the whole walk unless ``frames`` is given, with the house's camera motion
(:func:`~panovocc_cli.datasets.trajectory.orient`). Everything is drawn from ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from .layout import REQUIRED, WALL_T, LayoutRetry, Opening, Room, overlap, place_scene
from .furniture import paints
from .house import CorridorHouse, visit_room
from .meshbuild import Paint
from .rooms import leaf_box
from .trajectory import orient, path_length, plan_path, resample

BUILDING_FLOORS = 3
"""Floors of a building unless given."""
MAX_FLOORS = 8
BUILDING_AREA = 2500.0
"""Square metres of floor (rooms, corridors, stair landings) the default building reaches at least: rooms are
added to every floor until it does."""
FLOOR_ROOMS = (2, 60)
"""Smallest and largest number of rooms on a floor (the corridor and the stair shaft not counted)."""
BUILDING_STEP = 0.2
"""Metres between consecutive poses along the walk unless ``frames`` is given (the house's 300-pose walk
steps 0.20-0.23 m)."""

_STREAM = 7927  # the building's random streams: plan [seed, _STREAM], floor f [seed, _STREAM, 1 + f, attempt],
#                 a room's furniture [*floor's, room, attempt], camera motion [seed, _STREAM, 0]
_KINDS = ["living", "bedroom", "dining", "office", "bedroom", "office", "bedroom", "living", "dining", "bedroom"]

RISE_MAX = 0.18  # metres: the tallest riser allowed
BLONDEL = 0.63  # metres: 2 risers + 1 tread (the comfortable stride)
WAIST = 0.12  # metres: thinnest part of a flight (its slab below the steps' inner corners)
LANDING = 1.8  # metres: depth of a floor landing (the shaft's door opens onto it)
WELL = 0.40  # metres: gap between the two flights
RAIL_H = 0.9  # metres: balustrade height above the nosings or the landing
RAIL_T = 0.04  # metres: balustrade thickness
STAIR_GAP = 0.45  # metres: how far before a flight the walk's floor part ends and starts
ROOM_ATTEMPTS = 40  # draws of one room's furniture before the whole floor is drawn again


@dataclass(frozen=True)
class Plan:
    """The floor plate every floor shares, laid out from the origin (metres, floor at z = 0).

    ``hc`` ceiling height, ``slab`` floor slab thickness, ``storey`` = hc + slab; stair: ``risers`` a storey
    (even), ``rise`` and ``tread`` a step, ``flight_w``; ``length`` the corridor's, ``corridor`` (y0, y1),
    ``shaft`` (x0, x1, y0, y1) the stair shaft (south row, west end), ``south`` / ``north`` the rooms'
    (x0, x1) in each row, ``depth`` the rows' (south, north) depths, ``paints`` the shaft's (walls, steps,
    balustrades: one stairwell through all floors, whose rooms each have their own).
    """

    hc: float
    slab: float
    storey: float
    risers: int
    rise: float
    tread: float
    flight_w: float
    length: float
    corridor: tuple[float, float]
    shaft: tuple[float, float, float, float]
    south: tuple[tuple[float, float], ...]
    north: tuple[tuple[float, float], ...]
    depth: tuple[float, float]
    paints: dict = field(default_factory=dict, compare=False)  # the stair shaft's, the same on every floor

    @property
    def steps(self) -> int:
        """Risers a flight (two flights a storey)."""
        return self.risers // 2

    @property
    def landing_edge(self) -> float:
        """x of the floor landings' east edge, where the flights start and end."""
        return self.shaft[0] + LANDING

    @property
    def half_landing(self) -> float:
        """x of the half landings' west edge (the last riser of the first flight)."""
        return self.landing_edge + (self.steps - 1) * self.tread

    @property
    def lanes(self) -> tuple[float, float]:
        """y of the walking line of the first (south) and second (north) flight."""
        y0, y1 = self.shaft[2:]
        return y0 + self.flight_w / 2, y1 - self.flight_w / 2

    def floor_area(self) -> float:
        """Square metres of floor one storey offers: rooms, corridor, stair landing."""
        (ds, dn), (c0, c1), s = self.depth, self.corridor, self.shaft
        return (sum(b - a for a, b in self.south) * ds + sum(b - a for a, b in self.north) * dn
                + self.length * (c1 - c0) + LANDING * (s[3] - s[2]))


def _stair_dims(hc: float) -> tuple[int, float, float, float]:
    """(risers a storey, rise, tread, slab) for ceiling height ``hc``: the slab is a riser plus the waist, so
    a flight's soffit runs from one landing's underside to the next; the riser count is the smallest even
    one that keeps risers at most ``RISE_MAX``."""
    n = 2 * int(np.ceil(((hc + WAIST) / RISE_MAX + 1) / 2))
    rise = (hc + WAIST) / (n - 1)
    return n, rise, BLONDEL - 2 * rise, rise + WAIST


def draw_plan(seed: int, floors: int, rooms: int | None) -> Plan:
    """The floor plate of building ``seed``: ``rooms`` a floor (None: the fewest for ``BUILDING_AREA`` m² over
    ``floors`` floors)."""
    rng = np.random.default_rng([seed, _STREAM])
    hc = float(rng.uniform(2.5, 2.8))
    cw = float(rng.uniform(1.5, 1.8))
    ds, dn = (float(x) for x in rng.uniform(3.8, 4.6, 2))
    pool_s, pool_n = rng.uniform(3.4, 4.6, FLOOR_ROOMS[1]), rng.uniform(3.4, 4.6, FLOOR_ROOMS[1])
    shaft_paints = paints(rng)
    n, rise, tread, slab = _stair_dims(hc)
    fw = (ds - WELL) / 2
    shaft_w = LANDING + (n // 2 - 1) * tread + max(1.5, fw)
    yc0 = ds + WALL_T
    yc1 = yc0 + cw

    def plan(k: int) -> Plan:
        n_s, n_n = (k - 1) // 2, k - (k - 1) // 2
        w_s, w_n = pool_s[:n_s].copy(), pool_n[:n_n].copy()
        ls = shaft_w + n_s * WALL_T + w_s.sum()
        ln = w_n.sum() + (n_n - 1) * WALL_T
        L = max(ls, ln)
        if n_s:  # both rows span the corridor's length
            w_s *= (L - shaft_w - n_s * WALL_T) / w_s.sum()
        w_n *= (L - (n_n - 1) * WALL_T) / w_n.sum()
        south, x = [], shaft_w + WALL_T
        for w in w_s:
            south.append((x, x + float(w)))
            x += float(w) + WALL_T
        north, x = [], 0.0
        for w in w_n:
            north.append((x, x + float(w)))
            x += float(w) + WALL_T
        return Plan(hc=hc, slab=slab, storey=hc + slab, risers=n, rise=rise, tread=tread, flight_w=fw,
                    length=float(L), corridor=(yc0, yc1), shaft=(0.0, shaft_w, 0.0, ds), south=tuple(south),
                    north=tuple(north), depth=(ds, dn), paints=shaft_paints)

    if rooms is not None:
        return plan(rooms)
    for k in range(FLOOR_ROOMS[0], FLOOR_ROOMS[1] + 1):
        p = plan(k)
        if floors * p.floor_area() >= BUILDING_AREA:
            return p
    raise PanovoccError(f"--floors {floors}: {BUILDING_AREA:.0f} m² needs more than {FLOOR_ROOMS[1]} rooms a floor")


class _Floor(CorridorHouse):
    """One floor of the building: ``rooms[0]`` the corridor, ``rooms[1]`` the stair shaft, then the south row
    (west to east) and the north row (west to east)."""

    def __init__(self, rng: np.random.Generator, plan: Plan, level: int, floors: int, stream: tuple[int, ...]):
        self.plan, self.level, self.floors, self.stream = plan, level, floors, stream
        n_rooms = len(plan.south) + len(plan.north)
        super().__init__(rng, n_rooms)

    @property
    def top(self) -> bool:
        return self.level == self.floors - 1

    def _layout(self, k: int) -> None:
        rng, p = self.rng, self.plan
        self.hc = p.hc  # every floor has the plan's ceiling height (the draw above keeps the streams aligned)
        yc0, yc1 = p.corridor
        corridor = Room(0, "corridor", 0.0, p.length, yc0, yc1)
        shaft = Room(1, "stair", *p.shaft)
        self.rooms += [corridor, shaft]
        kinds = [_KINDS[i % len(_KINDS)] for i in range(k)]
        kinds = [kinds[i] for i in rng.permutation(k)]
        south = [Room(len(self.rooms) + i, kinds[i], x0, x1, 0.0, p.depth[0]) for i, (x0, x1) in enumerate(p.south)]
        self.rooms += south
        n0 = len(self.rooms)
        north = [Room(n0 + i, kinds[len(south) + i], x0, x1, yc1 + WALL_T, yc1 + WALL_T + p.depth[1])
                 for i, (x0, x1) in enumerate(p.north)]
        self.rooms += north
        self._corridor_doors(corridor, ((south, "N"), (north, "S")))
        if south:
            shaft.shared["E"], south[0].shared["W"] = south[0].idx, shaft.idx
        # the shaft's door: an open doorway (no leaf) from its landing onto the corridor
        shaft.shared["N"] = 0
        w = rng.uniform(0.92, 1.0)
        s0 = shaft.x0 + (LANDING - w) / 2
        zt = rng.uniform(2.05, 2.12)
        shaft.openings.append(Opening("door", "N", s0, s0 + w, 0.0, zt, other=0, owner=True, leaf_here=False))
        corridor.openings.append(Opening("door", "S", s0, s0 + w, 0.0, zt, other=1, owner=False, leaf_here=False))
        if self.level == 0:
            w = min(0.95, yc1 - yc0 - 0.3)
            s0 = (yc0 + yc1 - w) / 2
            corridor.openings.append(Opening("entrance", "W", s0, s0 + w, 0.0, 2.1))
        self._windows(self.rooms[2:])
        self._set_keepouts()
        # the walk stays on the landing: the flights (and the balustrade at the landing's edge) are obstacles
        self.obstacles.append((p.landing_edge - RAIL_T, shaft.x1, shaft.y0, shaft.y1))

    def furnish(self) -> None:
        for room in self.rooms:
            if room.kind == "corridor":
                self._furnish_corridor(room, plants=2)
            elif room.kind != "stair":
                self._furnish_walkable(room)

    def _furnish_walkable(self, room: Room) -> None:
        """Furnish ``room`` so that its two viewpoints can be walked to from its door: a draw that fails (no
        spot for a piece, a viewpoint boxed in) is undone and drawn again from the room's own stream, so one
        crowded room of a long floor does not redraw the whole floor."""
        floor_rng = self.rng
        for attempt in range(ROOM_ATTEMPTS):
            cp = self._checkpoint()
            self.rng = self.mb.rng = np.random.default_rng([*self.stream, room.idx, attempt])
            try:
                self._furnish_room(room)
                _check_room_walk(self, room)
                break
            except LayoutRetry:
                self._rollback(cp)
        else:
            raise LayoutRetry
        self.rng = self.mb.rng = floor_rng

    def build_shell(self) -> None:
        for room in self.rooms:
            if room.kind == "stair":
                self._shaft(room)
                continue
            self._floor(room)
            long = max(room.x1 - room.x0, room.y1 - room.y0)
            self._ceiling(room, lights=max(1, int(round(long / 4.0))) if room.kind == "corridor" else None)
            for side in "SNWE":
                self._wall(room, side)

    # ---- the stair shaft ------------------------------------------------------------------------
    def _shaft(self, room: Room) -> None:
        """The shaft's part on this floor: landing floor (the whole shaft on the ground floor), walls up to the
        next floor (to the ceiling on the top floor), the landing's (or, on top, the shaft's) ceiling, and
        the flights and half landing that rise to the next floor."""
        p, mb = self.plan, self.mb
        xa = p.landing_edge
        landing = Room(-1, "landing", room.x0, xa, room.y0, room.y1)
        self._floor(room if self.level == 0 else landing)
        self._ceiling(room if self.top else landing, lights=1)
        for side in "SNWE":
            self._wall(room, side, top=None if self.top else p.storey, paint=p.paints["wall"])
        stair = mb.new_object("stair", tint=0.03)
        rail = mb.new_object("handrail", tint=0.03)
        y0, y1 = room.y0, room.y1
        fw = p.flight_w
        if self.level > 0:  # the landing's slab edge over the well (on top also over the first flight's void)
            edge = (y0, y1 - fw) if self.top else (y0 + fw, y1 - fw)
            self._vquad(stair, p.paints["white"], xa, edge, -p.slab, 0.0, +1)
            self._rail_x(rail, xa - RAIL_T / 2, edge, 0.0)  # and its balustrade
        if not self.top:
            self._flights(stair, rail, room)

    def _vquad(self, obj: int, paint: Paint, x: float, ys: tuple[float, float], z0: float, z1: float,
               facing: int) -> None:
        """A vertical rectangle in the plane x = ``x``, facing +x (``facing`` = 1) or -x."""
        q = np.array([[x, ys[0], z0], [x, ys[1], z0], [x, ys[1], z1], [x, ys[0], z1]])  # counter-clockwise from +x
        self.mb.quads(obj, paint, q if facing > 0 else q[::-1])

    def _rail_x(self, obj: int, x: float, ys: tuple[float, float], z: float) -> None:
        """A balustrade panel across the shaft (centred on the plane x = ``x``) standing on height ``z``."""
        self.mb.box(obj, self.plan.paints["metal"], (x, (ys[0] + ys[1]) / 2, z + RAIL_H / 2), (RAIL_T, ys[1] - ys[0], RAIL_H),
                    omit=("-z",), cell=0.5)

    def _rail_sloped(self, obj: int, y: float, xs: tuple[float, float], zs: tuple[float, float]) -> None:
        """A balustrade panel along a flight (in the plane y = ``y``), its foot on the nosing line from
        (xs[0], zs[0]) to (xs[1], zs[1])."""
        h = RAIL_T / 2
        quads = []
        for yy, sgn in ((y - h, -1), (y + h, 1)):
            q = [(xs[0], yy, zs[0]), (xs[1], yy, zs[1]), (xs[1], yy, zs[1] + RAIL_H), (xs[0], yy, zs[0] + RAIL_H)]
            n = np.cross(np.subtract(q[1], q[0]), np.subtract(q[3], q[0]))
            quads.append(q if n[1] * sgn > 0 else q[::-1])
        top = [(xs[0], y - h, zs[0] + RAIL_H), (xs[1], y - h, zs[1] + RAIL_H), (xs[1], y + h, zs[1] + RAIL_H),
               (xs[0], y + h, zs[0] + RAIL_H)]
        n = np.cross(np.subtract(top[1], top[0]), np.subtract(top[3], top[0]))
        quads.append(top if n[2] > 0 else top[::-1])
        self.mb.quads(obj, self.plan.paints["metal"], np.array(quads, dtype=np.float64))

    def _flights(self, stair: int, rail: int, room: Room) -> None:
        """Both flights of this storey and the half landing between them (floor-local z: 0 here, the
        next floor at ``storey``)."""
        p, mb = self.plan, self.mb
        pt = p.paints
        m, r, g, t = p.steps, p.rise, p.tread, p.slab
        H = p.storey
        xa, xh = p.landing_edge, p.half_landing
        y0, y1, fw = room.y0, room.y1, p.flight_w
        run = (m - 1) * g
        # the half landing: top, underside, its edge over the well (the flights close it in their lanes)
        mb.grid(stair, pt["wood"], (xh, y0, H / 2), (1, 0, 0), (0, 1, 0), [0, room.x1 - xh], [0, y1 - y0],
                (0, 0, 1))
        mb.grid(stair, pt["white"], (xh, y0, H / 2 - t), (1, 0, 0), (0, 1, 0), [0, room.x1 - xh], [0, y1 - y0],
                (0, 0, -1))
        self._vquad(stair, pt["white"], xh, (y0 + fw, y1 - fw), H / 2 - t, H / 2, -1)
        ground = 0.0 if self.level == 0 else -np.inf
        for flight in (0, 1):
            # walking direction +x (first flight, south lane) or -x (second, north lane); u = distance walked
            sgn, x_foot, z_foot = (1.0, xa, 0.0) if flight == 0 else (-1.0, xh, H / 2)
            lane = (y0, y0 + fw) if flight == 0 else (y1 - fw, y1)
            y_well = lane[1] if flight == 0 else lane[0]
            well_n = 1.0 if flight == 0 else -1.0

            def X(u, x_foot=x_foot, sgn=sgn):
                return x_foot + sgn * np.asarray(u, dtype=np.float64)

            def soffit(u, z_foot=z_foot):  # from the lower landing's underside to the upper one's
                return np.maximum(z_foot - t + np.asarray(u) * (H / 2) / run, ground)

            risers, treads = [], []
            for i in range(1, m + 1):  # riser i at u = (i - 1) g, tread i on top of it
                u0 = (i - 1) * g
                risers.append(self._riser(X(u0), lane, z_foot + (i - 1) * r, z_foot + i * r, -sgn))
                if i < m:
                    treads.append(self._tread(X(u0), X(u0 + g), lane, z_foot + i * r))
            mb.quads(stair, pt["wood"], np.array(treads))
            mb.quads(stair, pt["white"], np.array(risers))
            # the side toward the well: between soffit and treads, broken where the soffit meets the ground
            us = np.arange(m) * g
            if self.level == 0 and flight == 0:
                us = np.unique(np.concatenate([us, [min(run, t * run / (H / 2))]]))
            side = []
            for ua, ub in zip(us[:-1], us[1:]):
                i = int(np.floor(ua / g + 1e-9)) + 1
                zt = z_foot + i * r
                za, zb = soffit(ua), soffit(ub)
                q = [(X(ua), y_well, za), (X(ub), y_well, zb), (X(ub), y_well, zt), (X(ua), y_well, zt)]
                n = np.cross(np.subtract(q[1], q[0]), np.subtract(q[3], q[0]))
                side.append(q if n[1] * well_n > 0 else q[::-1])
            mb.quads(stair, pt["white"], np.array(side, dtype=np.float64))
            # the soffit, facing down (on the ground floor only where it is above the ground)
            u_lo = 0.0 if self.level > 0 or flight == 1 else min(run, t * run / (H / 2))
            if u_lo < run:
                q = np.array([(X(u_lo), lane[0], soffit(u_lo)), (X(run), lane[0], soffit(run)),
                              (X(run), lane[1], soffit(run)), (X(u_lo), lane[1], soffit(u_lo))], dtype=np.float64)
                mb.quads(stair, pt["white"], (q if np.cross(q[1] - q[0], q[3] - q[0])[2] < 0 else q[::-1])[None])
            # the balustrade along the well, its foot on the nosing line
            y_rail = y_well - well_n * RAIL_T / 2
            self._rail_sloped(rail, y_rail, (float(X(0.0)), float(X(run))), (z_foot + r, z_foot + m * r))
        self._rail_x(rail, xh + RAIL_T / 2, (y0 + fw, y1 - fw), H / 2)

    @staticmethod
    def _riser(x: float, lane: tuple[float, float], z0: float, z1: float, facing: float) -> np.ndarray:
        q = np.array([[x, lane[0], z0], [x, lane[1], z0], [x, lane[1], z1], [x, lane[0], z1]])
        n = np.cross(q[1] - q[0], q[3] - q[0])
        return q if n[0] * facing > 0 else q[::-1]

    @staticmethod
    def _tread(xa: float, xb: float, lane: tuple[float, float], z: float) -> np.ndarray:
        x0, x1 = min(xa, xb), max(xa, xb)
        return np.array([[x0, lane[0], z], [x1, lane[0], z], [x1, lane[1], z], [x0, lane[1], z]])


def _check_room_walk(house: _Floor, room: Room) -> None:
    """Raise :class:`LayoutRetry` unless the walk from ``room``'s door to its two viewpoints and back exists
    with the trajectory's clearance, planned on the room alone (the floor's plan can only have more room)."""
    d = next(o for o in room.openings if o.kind == "door" and o.other == 0)
    box = (room.x0, room.x1, room.y0, room.y1)
    near = [b for b in house.obstacles if overlap(b, box, 0.5)]
    alone = SimpleNamespace(rooms=[room], obstacles=near + [leaf_box(room, d)])  # the leaf comes with the shell

    def tour(_, centers, views, snap):
        inside = snap(room.P(d.side, (d.s0 + d.s1) / 2, -0.6, 0.0)[:2], room)
        return [inside, *views(room), inside]

    plan_path(alone, tour)


def _floor_tour(level: int, floors: int, descend: bool = False):
    """The waypoints of floor ``level``'s part of the walk: from the entrance (ground floor) or the stair
    landing, into every room (south row eastward, then north row westward; through the door, its two
    viewpoints, back out), then (below the top floor, or on every floor with ``descend``) back to the landing,
    at the foot of the first flight."""

    def tour(house: _Floor, centers: np.ndarray, views, snap) -> list[int]:
        p = house.plan
        C, S = house.rooms[0], house.rooms[1]
        ya, yb = p.lanes
        xl = p.landing_edge - STAIR_GAP
        sd = next(o for o in S.openings if o.kind == "door")
        sm = (sd.s0 + sd.s1) / 2
        shaft_in, shaft_out = snap(S.P("N", sm, -0.6, 0.0)[:2], S), snap(S.P("N", sm, WALL_T + 0.6, 0.0)[:2], C)
        if level == 0:
            ent = next(o for o in C.openings if o.kind == "entrance")
            way = [snap(C.P(ent.side, (ent.s0 + ent.s1) / 2, -0.6, 0.0)[:2], C)]
        else:
            way = [snap(np.array([xl, yb]), S), shaft_in, shaft_out]
        rooms = house.rooms[2:]
        south = [r for r in rooms if r.y1 <= C.y0]
        north = [r for r in rooms if r.y0 >= C.y1]
        for r in sorted(south, key=lambda r: r.x0) + sorted(north, key=lambda r: -r.x0):
            way += visit_room(r, C, centers, views, snap)
        if level < floors - 1 or descend:
            way += [shaft_out, shaft_in, snap(np.array([S.x0 + 0.55, ya]), S), snap(np.array([xl, ya]), S)]
        return way

    return tour


def _leg(fl: "_Floor", a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The floor's clearance-weighted path from ``a`` to ``b`` (metres, (2,)), with its ends put at exactly
    ``a`` and ``b`` (both are points of the floor's own walk, so they lie on free nodes' paths already)."""
    path = plan_path(fl, lambda house, centers, views, snap: [snap(a), snap(b)], reach=3.0)
    path[0], path[-1] = a, b
    return path


def _stair_walk(p: Plan, start: np.ndarray, z_floor: float, step: float = 0.05) -> np.ndarray:
    """The walk up one storey: (n, 3) points (x, y, height of the feet) about ``step`` apart, from ``start``
    (the end of the floor's walk, on the landing by the first flight) along the first flight's walking
    line, round the half landing, up the second flight to the next floor's landing, ``STAIR_GAP`` short of
    the flight. The feet ride on the treads' middles: they rise one riser per tread."""
    H, r, g = p.storey, p.rise, p.tread
    xa, xh = p.landing_edge, p.half_landing
    ya, yb = p.lanes
    xc = xh + 0.4
    ax = p.shaft[1] - 0.45 - xc
    ay = (yb - ya) / 2

    def line(a, b):
        n = max(2, int(np.ceil(np.linalg.norm(np.subtract(b, a)) / step)) + 1)
        return np.linspace(a, b, n)

    first = line(start[:2], [xc, ya])
    feet1 = np.clip(r * ((first[:, 0] - xa) / g + 0.5), 0.0, H / 2)
    th = np.linspace(0.0, np.pi, max(8, int(np.ceil(np.pi * max(ax, ay) / step))))
    turn = np.stack([xc + ax * np.sin(th), (ya + yb) / 2 - ay * np.cos(th)], 1)
    second = line([xc, yb], [xa - STAIR_GAP, yb])
    feet2 = H / 2 + np.clip(r * ((xh - second[:, 0]) / g + 0.5), 0.0, H / 2)
    xy = np.concatenate([first, turn[1:-1], second])
    feet = np.concatenate([feet1, np.full(len(turn) - 2, H / 2), feet2])
    return np.column_stack([xy, z_floor + feet])


def generate_building(seed: int = DEFAULT_SEED, floors: int | None = None, rooms: int | None = None,
                      frames: int | None = None, offset: tuple[float, float, float] | None = None,
                      descend: bool = False) -> dict:
    """A building-scale scene and its walk (pure, no file I/O).

    Parameters
    ----------
    seed : random seed; floors : 2-8 (None: ``BUILDING_FLOORS``); rooms : rooms a floor, 2-60 (None: the
    fewest that give ``BUILDING_AREA`` m² in all); frames : poses along the walk (None: one every
    ``BUILDING_STEP`` metres); offset : (x, y, z) metres the building is moved (None:
    :func:`~panovocc_cli.datasets.layout.lattice_offset`); descend : after the top floor's rooms the walk goes
    back to its landing, down every flight (each floor's landing crossed from the flight it arrives by to the
    one it leaves by) and on the ground floor out of the stair shaft along the corridor to the entrance where
    it began: a walk that comes back to a floor it left for the floors above (the same scene; the walk up is
    the same but for the top floor's way back to its landing).

    Returns
    -------
    :func:`~panovocc_cli.datasets.layout.place_scene`'s dict (``rooms`` every floor's rooms, floor by floor,
    each floor's corridor and stair shaft first) and ``room_kinds``, ``room_floors`` (floor of each room),
    ``floor_heights`` (floors, ) float64 metres (world z of each floor), ``storey`` metres floor to floor,
    ``ceiling_height``, ``floor_area`` m², ``stair`` (x0, x1, y0, y1) the shaft (world), ``landing_edge``
    (world x where the flights start), ``rise`` and ``tread`` metres, ``risers`` a storey.
    """
    floors = BUILDING_FLOORS if floors is None else floors
    if not 2 <= floors <= MAX_FLOORS:
        raise PanovoccError(f"--floors must be between 2 and {MAX_FLOORS}, got {floors}")
    lo, hi = FLOOR_ROOMS
    if rooms is not None and not lo <= rooms <= hi:
        raise PanovoccError(f"--rooms with --building (rooms a floor) must be between {lo} and {hi}, got {rooms}")
    if frames is not None and frames < 2:
        raise PanovoccError(f"--frames must be at least 2, got {frames}")
    plan = draw_plan(seed, floors, rooms)
    meshes, classes, all_rooms, kinds, room_floors, walk = [], [], [], [], [], []
    start = None
    built, paths, ups = [], [], []  # each floor and its walk, each stair walk up (descend)
    for level in range(floors):
        z = level * plan.storey
        for attempt in range(60):
            stream = (seed, _STREAM, 1 + level, attempt)
            try:
                fl = _Floor(np.random.default_rng(stream), plan, level, floors, stream)
                fl.furnish()
                fl.build_shell()
                path = plan_path(fl, _floor_tour(level, floors, descend), reach=3.0)
            except LayoutRetry:
                continue
            break
        else:
            raise PanovoccError(f"could not lay out floor {level} of the building for seed {seed} (try another seed)")
        if start is not None:  # the stair walk ends where this floor's walk begins
            walk[-1][-1, :2] = path[0]
        part = np.column_stack([path, np.full(len(path), z)])
        walk.append(part)
        built.append(fl)
        paths.append(path)
        if level < floors - 1:
            walk.append(_stair_walk(plan, path[-1], z)[1:])
            ups.append(walk[-1])
            start = walk[-1][-1]
        v, q, obj, col = fl.mb.finish()
        meshes.append((v + np.array([0.0, 0.0, z]), q, obj, col))
        classes.append(list(fl.mb.object_classes))
        all_rooms += fl.rooms
        kinds += [r.kind for r in fl.rooms]
        room_floors += [level] * len(fl.rooms)
    if descend:  # down every flight (each the way up, reversed) to the ground floor, then out to the entrance
        for level in range(floors - 2, -1, -1):
            above = paths[level + 1]
            across = _leg(built[level + 1], above[-1], above[0])  # the landing: from the flight down to the other
            walk.append(np.column_stack([across, np.full(len(across), (level + 1) * plan.storey)]))
            walk.append(ups[level][::-1])  # the next leg starts at paths[level][-1], where the walk up began
        out = _leg(built[0], paths[0][-1], paths[0][0])
        walk.append(np.column_stack([out, np.zeros(len(out))]))  # (repeated points go below)
    names = [c for cl in classes for c in cl]
    if not set(REQUIRED) <= {canonical_name(c) for c in names}:
        raise PanovoccError(f"building {seed}: a class of {', '.join(REQUIRED)} is missing (try another seed)")
    mesh = _merge(meshes, classes)
    dense = np.concatenate(walk)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(dense, axis=0), axis=1) > 1e-9])
    dense = dense[keep]
    n = max(2, int(round(path_length(dense) / BUILDING_STEP)) + 1) if frames is None else frames
    T = orient(resample(dense, n), dense, np.random.default_rng([seed, _STREAM, 0]))
    g = place_scene(mesh, names, all_rooms, T, seed, offset, room_kinds=kinds, room_floors=room_floors,
                    ceiling_height=plan.hc, storey=plan.storey, floor_area=floors * plan.floor_area(),
                    rise=plan.rise, tread=plan.tread, risers=plan.risers)
    sx, sy, sz = g["offset"]
    g["floor_heights"] = sz + plan.storey * np.arange(floors)
    s = plan.shaft
    g["stair"] = (s[0] + sx, s[1] + sx, s[2] + sy, s[3] + sy)
    g["landing_edge"] = plan.landing_edge + sx
    return g


def _merge(meshes, classes):
    """One mesh from the floors' ``(vertices, quads, face_object, colors)``, object ids renumbered."""
    vs, qs, objs, cols = [], [], [], []
    nv = no = 0
    for (v, q, obj, col), cl in zip(meshes, classes):
        vs.append(v)
        qs.append(q + nv)
        objs.append(obj + no)
        cols.append(col)
        nv += len(v)
        no += len(cl)
    return (np.concatenate(vs), np.concatenate(qs).astype(np.int32), np.concatenate(objs).astype(np.int32),
            np.concatenate(cols))
