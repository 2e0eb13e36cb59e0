"""Small procedural homes (``panovocc synth``): one to six rooms on a grid, a trajectory through every one.

The rooms lie on a grid (a row for up to three, snake order beyond), separated by 12 cm walls. Rooms that
follow each other in the snake order share an interior door (an open leaf swung into one room); the
first room has a closed entrance door; every room has windows in its exterior walls (holes with reveals,
glass panes, frames, curtains). Rooms are furnished and built by :class:`~panovocc_cli.datasets.rooms.Home`.
The trajectory visits every room in turn, through the door to the next
(:mod:`~panovocc_cli.datasets.trajectory`). Everything is drawn from ``np.random.default_rng(seed)``.
"""

from __future__ import annotations

import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from .layout import OPPOSITE, REQUIRED, WALL_T, LayoutRetry, Opening, Room, place_scene
from .rooms import Home
from .trajectory import route

MAX_ROOMS = 6
SMALL_FRAMES = 60
"""Trajectory poses of a small home unless given."""


class GridHome(Home):
    """Rooms on a grid (a row up to three, then two rows in snake order), a door from each to the next."""

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
            b.openings.append(Opening("door", OPPOSITE[side], s0, s0 + w, 0.0, zt, other=i, owner=False,
                                      leaf_here=not leaf_in_a, hinge_s0=hinge))
        # Entrance door in the first room, windows in every room's exterior walls.
        for room in self.rooms:
            ext = [s for s in "SNWE" if s not in room.shared]
            rng.shuffle(ext)
            ext.sort(key=lambda s: -(room.side_range(s)[1] - room.side_range(s)[0]))
            if room.idx == 0 and ext:
                side = ext[-1] if len(ext) > 1 else ext[0]
                if not self._add_opening(room, side, "entrance", rng.uniform(0.9, 1.0), 0.0, 2.1):
                    raise LayoutRetry
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
                raise LayoutRetry
        self._set_keepouts()


def _plan(house: Home, frames: int, rng: np.random.Generator) -> np.ndarray:
    """The trajectory of a snake-order home: every room in turn, through the door to the next."""
    return route(house, frames, rng, _snake_tour)


def _snake_tour(house: Home, centers: np.ndarray, views, snap) -> list[int]:
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



def generate_scene(seed: int = DEFAULT_SEED, rooms: int | None = None, frames: int = SMALL_FRAMES,
                   offset: tuple[float, float, float] | None = None):
    """Generate a procedural scene and its trajectory (pure, no file I/O).

    ``offset``: (x, y, z) metres by which the home (laid out from the origin) is moved; None draws it
    from the seed (:func:`~panovocc_cli.datasets.layout.lattice_offset`). The layout itself does not
    depend on it. Returns :func:`~panovocc_cli.datasets.layout.place_scene`'s dict, with
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
            house = GridHome(rng, k)
            house.furnish()
            house.build_shell()
            T = _plan(house, frames, rng)
        except LayoutRetry:
            continue
        classes = {canonical_name(c) for c in house.mb.object_classes}
        if not set(REQUIRED) <= classes:
            continue
        # the home is laid out from (0, 0, 0) and moved by a seeded (or the user's) offset: anywhere
        # relative to the voxel lattice, planes exactly on a face included
        return place_scene(house.mb.finish(), house.mb.object_classes, house.rooms, T, seed, offset,
                           ceiling_height=house.hc)
    raise PanovoccError(f"could not lay out a {k}-room scene for seed {seed} (try another seed)")
