"""House-scale procedural homes (``panovocc synth --house``): six to eight rooms off a corridor.

The corridor (1.3-1.6 m wide) runs along x; rooms line both of its sides (west to east, south row first),
each with its door onto the corridor (the leaf swung into the room, so the corridor stays clear), the
entrance door at the corridor's west end, windows in every room's exterior walls. Rooms are furnished
by the same builders as the small homes (:mod:`panovocc_cli.datasets.rooms`: a living room with sofa, TV
cabinet, coffee table, lamp and shelf; a dining room; bedrooms with beds, nightstands, wardrobes and desks; an office),
the corridor gets a sideboard and a plant. The trajectory starts at the entrance and walks the corridor,
entering every room in the order of its door: through the door, to the room's two viewpoints, and back
out (the same clearance-weighted shortest paths, smoothing and camera motion as the small scenes).
"""

from __future__ import annotations

import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from .furniture import cabinet
from .layout import OPPOSITE, REQUIRED, WALL_T, LayoutRetry, Opening, Room, place_scene
from .rooms import Home
from .trajectory import route

HOUSE_ROOMS = (6, 8)
"""Smallest and largest number of rooms of a house (the corridor not counted)."""
HOUSE_FRAMES = 300
"""Trajectory poses of a house unless given."""
_KINDS = ["living", "dining", "bedroom", "office", "bedroom", "bedroom", "office", "bedroom"]


class CorridorHouse(Home):
    """A :class:`~panovocc_cli.datasets.rooms.Home` laid out as rooms on both sides of a corridor
    (``rooms[0]``), each opening onto it."""

    def _layout(self, k: int) -> None:
        rng = self.rng
        n_s, n_n = (k + 1) // 2, k // 2
        cw = float(rng.uniform(1.3, 1.6))
        w_s, w_n = rng.uniform(3.4, 4.6, n_s), rng.uniform(3.4, 4.6, n_n)
        L = max(w_s.sum() + (n_s - 1) * WALL_T, w_n.sum() + (n_n - 1) * WALL_T)
        w_s *= (L - (n_s - 1) * WALL_T) / w_s.sum()  # both rows span the corridor's length
        w_n *= (L - (n_n - 1) * WALL_T) / w_n.sum()
        d_s, d_n = rng.uniform(3.6, 4.6), rng.uniform(3.6, 4.6)
        yc0 = d_s + WALL_T
        yc1 = yc0 + cw
        corridor = Room(0, "corridor", 0.0, L, yc0, yc1)
        self.rooms.append(corridor)
        kinds = [_KINDS[i] for i in rng.permutation(k)]
        row_s, row_n = [], []
        x = 0.0
        for w in w_s:
            row_s.append(Room(len(self.rooms), kinds.pop(), x, x + w, 0.0, d_s))
            self.rooms.append(row_s[-1])
            x += w + WALL_T
        x = 0.0
        for w in w_n:
            row_n.append(Room(len(self.rooms), kinds.pop(), x, x + w, yc1 + WALL_T, yc1 + WALL_T + d_n))
            self.rooms.append(row_n[-1])
            x += w + WALL_T
        self._corridor_doors(corridor, ((row_s, "N"), (row_n, "S")))
        w = min(0.95, cw - 0.3)
        s0 = (yc0 + yc1 - w) / 2
        corridor.openings.append(Opening("entrance", "W", s0, s0 + w, 0.0, 2.1))
        self._windows(self.rooms[1:])
        self._set_keepouts()

    def _corridor_doors(self, corridor: Room, rows) -> None:
        """Rows of rooms along ``corridor``, ``rows`` = ((rooms west to east, side facing the corridor), ...):
        neighbours in a row share a wall; each room gets a door onto the corridor, its leaf swung into the
        room (0.9-1.0 m wide, 2.05-2.12 m high, anywhere 0.35 m clear of the room's corners)."""
        rng = self.rng
        for row, side in rows:
            for a, b in zip(row[:-1], row[1:]):
                a.shared["E"] = b.idx
                b.shared["W"] = a.idx
            for r in row:
                r.shared[side] = corridor.idx
                corridor.shared[OPPOSITE[side]] = r.idx
                w = rng.uniform(0.9, 1.0)
                s0 = rng.uniform(r.x0 + 0.35, r.x1 - 0.35 - w)
                zt = rng.uniform(2.05, 2.12)
                hinge = bool(rng.integers(2))
                r.openings.append(Opening("door", side, s0, s0 + w, 0.0, zt, other=corridor.idx, owner=True,
                                          leaf_here=True, hinge_s0=hinge))
                corridor.openings.append(Opening("door", OPPOSITE[side], s0, s0 + w, 0.0, zt, other=r.idx,
                                                 owner=False, leaf_here=False, hinge_s0=hinge))

    def _windows(self, rooms) -> None:
        """One or two windows (0.9-1.5 m wide, sill 0.9-1.0 m) in the exterior walls of each of ``rooms``,
        longest walls first; a room without one is a failed draw."""
        rng = self.rng
        for room in rooms:
            ext = [s for s in "SNWE" if s not in room.shared]
            rng.shuffle(ext)
            ext.sort(key=lambda s: -(room.side_range(s)[1] - room.side_range(s)[0]))
            n_win = 0
            for j, side in enumerate(ext):
                if n_win >= 2 or (j > 0 and rng.random() < 0.7):
                    continue
                for _ in range(1 if rng.random() < 0.8 else 2):
                    z1 = min(self.hc - 0.3, rng.uniform(2.05, 2.25))
                    n_win += self._add_opening(room, side, "window", rng.uniform(0.9, 1.5), rng.uniform(0.9, 1.0), z1)
            if n_win == 0:
                raise LayoutRetry

    def furnish(self) -> None:
        for room in self.rooms:
            if room.kind == "corridor":
                self._furnish_corridor(room, plants=1)
            else:
                self._furnish_room(room)  # the house always has a dining room: no extra dining set

    def _furnish_corridor(self, room: Room, plants: int) -> None:
        """A sideboard on the corridor's east end wall, ``plants`` plants in its corners."""
        cw = room.y1 - room.y0
        spot = self._on_wall(room, min(1.0, cw - 0.2), 0.35, sides=["E"])
        if spot is not None:
            tf, box, _, _ = spot
            cabinet(self.mb, self.pt, tf, min(1.0, cw - 0.2), 0.35, 0.9, doors=2)
            self.obstacles.append(box)
        self._extras(room, plants=plants, shelf=False)


def visit_room(r: Room, corridor: Room, centers: np.ndarray, views, snap) -> list[int]:
    """The waypoints of one room's visit from ``corridor``: through its door, to its two viewpoints (nearer
    first), back out (a :func:`~panovocc_cli.datasets.trajectory.plan_path` tour's piece)."""
    d = next(o for o in r.openings if o.kind == "door" and o.other == corridor.idx)
    m = (d.s0 + d.s1) / 2
    outside = snap(r.P(d.side, m, WALL_T + 0.6, 0.0)[:2], corridor)
    inside = snap(r.P(d.side, m, -0.6, 0.0)[:2], r)
    v = views(r)
    v.sort(key=lambda k: np.linalg.norm(centers[k] - centers[inside]))
    return [outside, inside, *v, inside, outside]


def _corridor_tour(house: Home, centers: np.ndarray, views, snap) -> list[int]:
    """From the entrance along the corridor, into every room (door order) and back out."""
    C = house.rooms[0]
    ent = next(o for o in C.openings if o.kind == "entrance")
    way = [snap(C.P(ent.side, (ent.s0 + ent.s1) / 2, -0.6, 0.0)[:2], C)]
    doors = [(r, next(o for o in r.openings if o.kind == "door" and o.other == 0)) for r in house.rooms[1:]]
    doors.sort(key=lambda rd: (rd[1].s0 + rd[1].s1) / 2)
    for r, _ in doors:
        way += visit_room(r, C, centers, views, snap)
    return way


def generate_house(seed: int = DEFAULT_SEED, rooms: int | None = None, frames: int = HOUSE_FRAMES,
                   offset: tuple[float, float, float] | None = None) -> dict:
    """A house-scale scene and its trajectory (pure, no file I/O); the same dict as
    :func:`panovocc_cli.datasets.home.generate_scene` (``rooms`` there lists the corridor first).

    Parameters
    ----------
    seed : random seed; rooms : 6-8 (None: 6, 7 or 8 from the seed); frames : poses along the trajectory
    offset : (x, y, z) metres the house is moved (None: :func:`~panovocc_cli.datasets.layout.lattice_offset`)
    """
    lo, hi = HOUSE_ROOMS
    if rooms is not None and not lo <= rooms <= hi:
        raise PanovoccError(f"--rooms with --house must be between {lo} and {hi}, got {rooms}")
    if frames < 2:
        raise PanovoccError(f"--frames must be at least 2, got {frames}")
    base = np.random.default_rng([seed, 7919])
    k = int(base.integers(lo, hi + 1)) if rooms is None else rooms
    for attempt in range(60):
        rng = np.random.default_rng([seed, 7919, attempt])
        try:
            house = CorridorHouse(rng, k)
            house.furnish()
            house.build_shell()
            T = route(house, frames, rng, _corridor_tour)
        except LayoutRetry:
            continue
        if not set(REQUIRED) <= {canonical_name(c) for c in house.mb.object_classes}:
            continue
        return place_scene(house.mb.finish(), house.mb.object_classes, house.rooms, T, seed, offset,
                           room_kinds=[r.kind for r in house.rooms], ceiling_height=house.hc)
    raise PanovoccError(f"could not lay out a {k}-room house for seed {seed} (try another seed)")
