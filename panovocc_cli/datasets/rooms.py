"""Furnished rooms and their shell: the part of a procedural home every layout shares.

A :class:`Home` holds rooms (:class:`~panovocc_cli.datasets.layout.Room`) that a subclass lays out in
``_layout`` (a grid of rooms: :mod:`~panovocc_cli.datasets.home`; rooms off a corridor:
:mod:`~panovocc_cli.datasets.house`; the floors of a building: :mod:`~panovocc_cli.datasets.building`).
It furnishes each room by its kind (living, bedroom, dining, office, studio) with the pieces of
:mod:`~panovocc_cli.datasets.furniture`, placed against walls or around tables, clear of doors and windows,
and builds the shell: plank floors (holes under rugs), ceilings with lights, walls with real holes for
doors and windows, reveals, glass panes, frames, curtains and door leaves. Surfaces face the room; nothing
is double-sided. ``obstacles`` collects the 2-D footprints the camera's path keeps clear of.
"""

from __future__ import annotations

import numpy as np

from . import furniture as fu
from .layout import NORMAL, OPPOSITE, WALL_T, LayoutRetry, Opening, Room, overlap, tf_yaw
from .meshbuild import MeshBuilder, Paint, Transform2D


class Home:
    """A procedural home being built: rooms, furniture and shell, drawn from ``rng`` in a fixed order.

    ``mb`` collects the mesh, ``pt`` the paints, ``hc`` the ceiling height (metres), ``obstacles`` the
    2-D boxes (x0, x1, y0, y1) the camera avoids; ``keepout`` and ``rugs`` are per-room placement state.
    """

    def __init__(self, rng: np.random.Generator, n_rooms: int):
        self.rng = rng
        self.mb = MeshBuilder(rng)
        self.pt = fu.paints(rng)
        self.hc = float(rng.uniform(2.5, 2.8))
        self.rooms: list[Room] = []
        self.obstacles: list[tuple[float, float, float, float]] = []  # 2-D boxes the camera must avoid
        self.keepout: dict[int, list] = {}
        self.rugs: dict[int, list] = {}
        self._layout(n_rooms)

    # ---- layout ---------------------------------------------------------------------------------
    def _layout(self, k: int) -> None:
        """Append ``k`` rooms (with their openings) to ``self.rooms``; end with ``self._set_keepouts()``."""
        raise NotImplementedError

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
        if any(overlap(box, k) and height > hmax for k, hmax in self.keepout[room.idx]):
            return False
        return not any(overlap(box, b, gap) for b in self.obstacles)

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
                n = NORMAL[side]
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
            fu.table(self.mb, self.pt, tf, w, d, 0.75)
            paint = fu.pick(rng, [self.pt["wood"], self.pt["metal"], self.pt["white"]])
            for ctf, _ in chairs:
                fu.chair(self.mb, ctf, paint)
            self.obstacles += boxes
            return True
        return False

    def _add_rug(self, room: Room, tf: Transform2D, w, d) -> None:
        box = self._local_box(tf, 0, 0, w, d)
        if (box[0] < room.x0 + 0.1 or box[1] > room.x1 - 0.1 or box[2] < room.y0 + 0.1 or box[3] > room.y1 - 0.1
                or any(overlap(box, r) for r in self.rugs.get(room.idx, []))):
            return
        self.rugs.setdefault(room.idx, []).append(box)
        fu.rug(self.mb, self.pt, Transform2D((box[0] + box[1]) / 2, (box[2] + box[3]) / 2), box[1] - box[0],
             box[3] - box[2])

    def _living(self, room: Room) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        w = rng.uniform(1.8, 2.3)
        spot = self._on_wall(room, w, 0.9, height=0.86)
        if spot is None:
            raise LayoutRetry
        tf, box, side, s = spot
        fu.sofa(mb, pt, tf, w)
        self.obstacles.append(box)
        ctw, ctd = rng.uniform(0.9, 1.2), rng.uniform(0.5, 0.6)
        cty = 0.45 + 0.45 + ctd / 2
        cbox = self._local_box(tf, 0, cty, ctw, ctd)
        if self._free(room, cbox, gap=0.2):
            rug_tf = Transform2D(*tf.point([0, cty - 0.1, 0])[:2], tf_yaw(tf))
            self._add_rug(room, rug_tf, min(w + 0.4, 2.4), 1.6)
            fu.table(mb, pt, Transform2D(*tf.point([0, cty, 0])[:2], tf_yaw(tf)), ctw, ctd, 0.42, leg=0.045)
            self.obstacles.append(cbox)
        lamp_x = (w / 2 + 0.3) * (1 if rng.random() < 0.5 else -1)
        lbox = self._local_box(tf, lamp_x, -0.2, 0.42, 0.42)
        if self._free(room, lbox):
            fu.floor_lamp(mb, pt, Transform2D(*tf.point([lamp_x, -0.2, 0])[:2]))
            self.obstacles.append(lbox)
        tvw = rng.uniform(1.0, 1.4)
        spot = self._on_wall(room, tvw + 0.3, 0.45, sides=[OPPOSITE[side]], near=s) or self._on_wall(
            room, tvw + 0.3, 0.45)
        if spot is None:
            raise LayoutRetry
        ttf, tbox, _, _ = spot
        fu.cabinet(mb, pt, ttf, tvw + 0.3, 0.45, 0.5, doors=3)
        fu.tv(mb, pt, Transform2D(*ttf.point([0, 0.0, 0])[:2], tf_yaw(ttf)), tvw, 0.5)
        self.obstacles.append(tbox)
        self._extras(room, plants=1 + int(rng.random() < 0.5), shelf=rng.random() < 0.7)

    def _bedroom(self, room: Room, desk: bool = True) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        bw, bl = fu.pick(rng, [1.4, 1.6, 1.8]), rng.uniform(2.0, 2.1)
        stands = True
        spot = self._on_wall(room, bw + 1.0, bl, height=1.04)
        if spot is None:
            stands = False
            spot = self._on_wall(room, bw, bl, height=1.04)
        if spot is None:
            raise LayoutRetry
        tf, box, side, s = spot
        fu.bed(mb, pt, tf, bw, bl)
        self.obstacles.append(self._local_box(tf, 0, 0, bw, bl))
        for sx in ((-1, 1) if stands else ()):
            x = sx * (bw / 2 + 0.27)
            ns = Transform2D(*tf.point([x, -bl / 2 + 0.2, 0])[:2], tf_yaw(tf))
            fu.cabinet(mb, pt, ns, 0.45, 0.4, 0.55, cls="nightstand", doors=1)
            fu.table_lamp(mb, pt, ns, 0.55)
            self.obstacles.append(self._local_box(ns, 0, 0, 0.45, 0.4))
        if rng.random() < 0.6:
            self._add_rug(room, Transform2D(*tf.point([0, bl / 2 + 0.1, 0])[:2], tf_yaw(tf)), bw + 0.6, 1.0)
        ww = rng.uniform(1.0, 1.6)
        spot = self._on_wall(room, ww, 0.6)
        if spot is not None:
            wtf, wbox, _, _ = spot
            fu.cabinet(mb, pt, wtf, ww, 0.6, 2.0)
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
        fu.table(self.mb, self.pt, Transform2D(*tf.point([0, -0.6 + 0.3, 0])[:2], tf_yaw(tf)), dw, 0.6, 0.74)
        fu.chair(self.mb, Transform2D(*tf.point([0, 0.25, 0])[:2], tf_yaw(tf) + np.pi), self.pt["metal"])
        self.obstacles.append(box)
        return True

    def _dining(self, room: Room) -> None:
        if not self._dining_set(room):
            raise LayoutRetry
        sw = self.rng.uniform(1.2, 1.8)
        spot = self._on_wall(room, sw, 0.45, height=0.85)
        if spot is not None:
            tf, box, _, _ = spot
            fu.cabinet(self.mb, self.pt, tf, sw, 0.45, 0.85, doors=3)
            self.obstacles.append(box)
        self._extras(room, plants=1 + int(self.rng.random() < 0.5), shelf=False)

    def _extras(self, room: Room, plants: int, shelf: bool) -> None:
        rng, mb, pt = self.rng, self.mb, self.pt
        for _ in range(plants):
            spot = self._on_wall(room, 0.6, 0.6, corner=True)
            if spot is not None:
                tf, box, _, _ = spot
                fu.plant(mb, pt, Transform2D(*tf.point([0, 0, 0])[:2]), rng)
                self.obstacles.append(box)
        if shelf:
            bw = rng.uniform(0.8, 1.2)
            spot = self._on_wall(room, bw, 0.32)
            if spot is not None:
                tf, box, _, _ = spot
                fu.bookshelf(mb, pt, tf, rng, bw)
                self.obstacles.append(box)

    def furnish(self) -> None:
        for room in self.rooms:
            self._furnish_room(room)

    def _checkpoint(self):
        """The state furnishing a room changes (mesh, obstacles, rugs), for :meth:`_rollback`."""
        return self.mb.mark(), len(self.obstacles), {k: len(v) for k, v in self.rugs.items()}

    def _rollback(self, cp) -> None:
        """Undo everything added since :meth:`_checkpoint` returned ``cp``."""
        mark, n_obst, rugs = cp
        self.mb.rollback(mark)
        del self.obstacles[n_obst:]
        for k in list(self.rugs):
            del self.rugs[k][rugs.get(k, 0):]

    def _furnish_room(self, room: Room) -> None:
        """Furniture for a room of kind living (a small dining set too when the home has no dining room),
        bedroom, dining, office or studio (bed, living corner and small dining set in one room)."""
        if room.kind == "living":
            self._living(room)
            if not any(r.kind == "dining" for r in self.rooms) and not self._dining_set(room, small=True):
                raise LayoutRetry
        elif room.kind == "bedroom":
            self._bedroom(room)
        elif room.kind == "dining":
            self._dining(room)
        elif room.kind == "office":
            if not self._desk(room):
                raise LayoutRetry
            self._extras(room, plants=1, shelf=True)
        elif room.kind == "studio":
            self._bedroom(room, desk=False)
            self._living(room)
            if not self._dining_set(room, small=True):
                raise LayoutRetry
        else:
            raise ValueError(f"no furniture for a room of kind {room.kind!r}")

    # ---- shell: floors, ceilings, walls, openings ----------------------------------------------
    def build_shell(self) -> None:
        for room in self.rooms:
            self._floor(room)
            self._ceiling(room)
            for side in "SNWE":
                self._wall(room, side)

    def _ceiling(self, room: Room, lights: int | None = None) -> None:
        """The ceiling over ``room`` at ``hc`` (0.5 m cells, facing down) with ``lights`` round ceiling lights
        along its long axis (None: two in a room longer than 4.6 m, else one)."""
        mb, pt, hc = self.mb, self.pt, self.hc
        ceil = mb.new_object("ceiling", tint=0.02)
        xs = np.linspace(room.x0, room.x1, int(np.ceil((room.x1 - room.x0) / 0.5)) + 1) - room.x0
        ys = np.linspace(room.y0, room.y1, int(np.ceil((room.y1 - room.y0) / 0.5)) + 1) - room.y0
        mb.grid(ceil, pt["ceiling"], (room.x0, room.y0, hc), (1, 0, 0), (0, 1, 0), xs, ys, (0, 0, -1))
        nl = (2 if max(room.x1 - room.x0, room.y1 - room.y0) > 4.6 else 1) if lights is None else lights
        for k in range(nl):
            f = (k + 0.5) / nl
            c = (room.x0 + f * (room.x1 - room.x0), room.center[1]) if room.x1 - room.x0 >= room.y1 - room.y0 \
                else (room.center[0], room.y0 + f * (room.y1 - room.y0))
            lo = mb.new_object("lamp")
            mb.cylinder(lo, pt["light"], c, hc - 0.09, hc, self.rng.uniform(0.18, 0.28), n=16, top=False,
                        bottom=True)

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

    def _wall(self, room: Room, side: str, top: float | None = None, paint: Paint | None = None) -> None:
        """The wall on ``side`` of ``room`` from the floor to ``top`` metres (None: the ceiling, ``hc``), 0.4 m
        cells, holes for its openings, and the openings' reveals, panes, curtains and leaves; ``paint`` for the
        wall and its reveals (None: the home's wall paint)."""
        mb, pt = self.mb, self.pt
        paint = pt["wall"] if paint is None else paint
        hc = self.hc if top is None else top
        wo = mb.new_object("wall", tint=0.015)
        lo, hi = room.side_range(side)
        ops = [o for o in room.openings if o.side == side]
        su = np.concatenate([np.linspace(lo, hi, int(np.ceil((hi - lo) / 0.4)) + 1)] + [[o.s0, o.s1] for o in ops])
        sv = np.concatenate([np.linspace(0, hc, int(np.ceil(hc / 0.4)) + 1)] + [[o.z0, o.z1] for o in ops])
        n3 = np.array([*NORMAL[side], 0.0])
        U = np.array([1.0, 0, 0]) if side in "SN" else np.array([0, 1.0, 0])

        def skip(sa, sb, ta, tb):  # cells of the wall's grid (offsets from ``lo``) inside an opening
            sc, tc = lo + (sa + sb) / 2, (ta + tb) / 2
            out = np.zeros(len(sa), bool)
            for o in ops:
                out |= (sc > o.s0) & (sc < o.s1) & (tc > o.z0) & (tc < o.z1)
            return out

        origin = room.P(side, lo, 0.0, 0.0)
        mb.grid(wo, paint, origin, U, (0, 0, 1), su - lo, sv, n3, skip=skip)
        for o in ops:
            self._opening(room, o, wo, U, n3, paint)

    def _opening(self, room: Room, o: Opening, wo: int, U: np.ndarray, n3: np.ndarray, paint: Paint) -> None:
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
            mb.rect(wo, paint, room.P(o.side, o.s0, 0, o.z0), out, z, depth, h, U, cell=0.4)
            mb.rect(wo, paint, room.P(o.side, o.s1, 0, o.z0), out, z, depth, h, -U, cell=0.4)
            mb.rect(wo, paint, room.P(o.side, o.s0, 0, o.z1), U, out, w, depth, -z, cell=0.4)
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
            s0, lw = _leaf(o)
            a = room.P(o.side, s0, -0.01, 0.005)
            b = room.P(o.side, s0 + 0.04, -0.01 - lw, o.z1 - 0.01)
            mb.box(d, pt["door"], (a + b) / 2, np.abs(b - a), omit=("-z",), cell=0.3)
            self.obstacles.append(leaf_box(room, o))

    def _curtains(self, room: Room, o: Opening) -> None:
        mb = self.mb
        c = mb.new_object("curtain")
        top = min(self.hc - 0.05, o.z1 + 0.15)
        n3 = np.array([*NORMAL[o.side], 0.0])
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


def _leaf(o: Opening) -> tuple[float, float]:
    """(wall coordinate where the open leaf of door ``o`` starts, the leaf's width), metres."""
    return (o.s0 + 0.005 if o.hinge_s0 else o.s1 - 0.045), (o.s1 - o.s0) - 0.02


def leaf_box(room: Room, o: Opening) -> tuple[float, float, float, float]:
    """The 2-D box (x0, x1, y0, y1) of door ``o``'s open leaf, 4 cm thick, standing at 90 degrees into ``room``."""
    s0, lw = _leaf(o)
    return room.aabb(o.side, s0, s0 + 0.04, -0.01 - lw, -0.01)
