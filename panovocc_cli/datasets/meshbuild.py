"""Building blocks for procedural scenes: quads with per-object paint, boxes, cylinders, blobs.

Everything is made of quads (Replica's face type). Each quad has its own four vertices, so colours can
change from one cell to the next (planks, tiles, fabric weave) like a scan's texture. Surfaces carry a
front side only; the caller says which way they face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Paint:
    """Vertex-colour recipe: ``rgb`` base (0..255), ``jitter`` per-cell brightness spread (std, relative),
    ``noise`` smooth brightness variation amplitude (relative), ``stripes`` (period metres, 0 = none) with
    ``stripe_rgb`` the second tone."""

    rgb: tuple[float, float, float]
    jitter: float = 0.03
    noise: float = 0.05
    stripes: float = 0.0
    stripe_rgb: tuple[float, float, float] = (0.0, 0.0, 0.0)


class Transform2D:
    """Placement of an item: rotation ``yaw`` (radians) about +Z, then translation ``(x, y, z)`` metres."""

    def __init__(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, z: float = 0.0):
        c, s = np.cos(yaw), np.sin(yaw)
        # Round so that 90-degree turns give exact axis-aligned geometry.
        self.R = np.round(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), 12)
        self.t = np.array([x, y, z], dtype=np.float64)

    def point(self, p) -> np.ndarray:
        return np.asarray(p, dtype=np.float64) @ self.R.T + self.t


IDENTITY = Transform2D()


class MeshBuilder:
    """Accumulates quads, objects (each with a Replica class name) and paints; :meth:`finish` colours them."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self._quads: list[np.ndarray] = []  # (n, 4, 3)
        self._obj: list[np.ndarray] = []  # (n,)
        self._paint: list[np.ndarray] = []  # (n,)
        self.paints: list[Paint] = []
        self._paint_index: dict[Paint, int] = {}
        self.object_classes: list[str] = []
        self.object_tint: list[float] = []
        self.object_waves: list[np.ndarray] = []

    # -- objects and paints --------------------------------------------------------------------------
    def new_object(self, cls: str, tint: float = 0.06) -> int:
        """Register an object of Replica class ``cls``; returns its id. ``tint``: per-object brightness spread."""
        self.object_classes.append(cls)
        self.object_tint.append(1.0 + tint * float(self.rng.standard_normal()))
        dirs = self.rng.standard_normal((3, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        freq = self.rng.uniform(2.0, 9.0, size=(3, 1))
        phase = self.rng.uniform(0, 2 * np.pi, size=(3, 1))
        self.object_waves.append(np.concatenate([dirs * freq, phase], axis=1))
        return len(self.object_classes) - 1

    def _pid(self, paint: Paint) -> int:
        if paint not in self._paint_index:
            self._paint_index[paint] = len(self.paints)
            self.paints.append(paint)
        return self._paint_index[paint]

    # -- primitives ----------------------------------------------------------------------------------
    def quads(self, obj: int, paint: Paint, quads: np.ndarray) -> None:
        """Add quads (n, 4, 3) world metres, vertices counter-clockwise seen from the front."""
        q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 3)
        if not len(q):
            return
        self._quads.append(q)
        self._obj.append(np.full(len(q), obj, np.int32))
        self._paint.append(np.full(len(q), self._pid(paint), np.int32))

    def grid(self, obj: int, paint: Paint, origin, U, V, su, sv, normal, skip=None, tf: Transform2D = IDENTITY):
        """A planar rectangle ``origin + s U + t V`` cut at breakpoints ``su`` x ``sv`` into quads facing ``normal``.

        ``U``, ``V`` unit vectors, ``su``/``sv`` increasing offsets (metres); ``skip(sa, sb, ta, tb)`` -> bool
        arrays drop cells (holes). All vectors are local and mapped through ``tf``.
        """
        su = np.unique(np.round(np.asarray(su, dtype=np.float64), 9))
        sv = np.unique(np.round(np.asarray(sv, dtype=np.float64), 9))
        if len(su) < 2 or len(sv) < 2:
            return
        sa, ta = np.meshgrid(su[:-1], sv[:-1], indexing="ij")
        sb, tb = np.meshgrid(su[1:], sv[1:], indexing="ij")
        sa, sb, ta, tb = sa.ravel(), sb.ravel(), ta.ravel(), tb.ravel()
        keep = np.ones(len(sa), bool) if skip is None else ~np.asarray(skip(sa, sb, ta, tb), bool)
        sa, sb, ta, tb = sa[keep], sb[keep], ta[keep], tb[keep]
        O, U, V = (np.asarray(x, dtype=np.float64) for x in (origin, U, V))
        corners = [(sa, ta), (sb, ta), (sb, tb), (sa, tb)]
        (u0, u1, u2), (v0, v1, v2), (n0, n1, n2) = U.tolist(), V.tolist(), np.asarray(normal, dtype=np.float64).tolist()
        if (u1 * v2 - u2 * v1) * n0 + (u2 * v0 - u0 * v2) * n1 + (u0 * v1 - u1 * v0) * n2 < 0:  # (U x V) . normal
            corners = corners[::-1]
        q = np.stack([O + s[:, None] * U + t[:, None] * V for s, t in corners], axis=1)
        self.quads(obj, paint, tf.point(q))

    def rect(self, obj, paint, origin, U, V, lu, lv, normal, cell=0.3, tf: Transform2D = IDENTITY):
        """Rectangle of size lu x lv (metres) subdivided into cells of about ``cell`` metres."""
        su = np.linspace(0, lu, max(1, int(np.ceil(lu / cell))) + 1)
        sv = np.linspace(0, lv, max(1, int(np.ceil(lv / cell))) + 1)
        self.grid(obj, paint, origin, U, V, su, sv, normal, tf=tf)

    def box(self, obj, paint, center, size, tf: Transform2D = IDENTITY, omit=(), cell=0.25):
        """Axis-aligned (in local coordinates) box with outward faces; ``omit`` names faces not built
        (``"-z"`` for a box standing on the floor, ``"-y"`` for one against a wall, ...)."""
        c = np.asarray(center, dtype=np.float64)
        h = np.asarray(size, dtype=np.float64) / 2
        E = np.eye(3)
        for ax in range(3):
            for sgn, name in ((1, "+"), (-1, "-")):
                if name + "xyz"[ax] in omit:
                    continue
                u, v = (ax + 1) % 3, (ax + 2) % 3
                origin = c - h[u] * E[u] - h[v] * E[v] + sgn * h[ax] * E[ax]
                self.rect(obj, paint, origin, E[u], E[v], 2 * h[u], 2 * h[v], sgn * E[ax], cell=cell, tf=tf)

    def cylinder(self, obj, paint, center_xy, z0, z1, radius, n=12, top=True, bottom=False,
                 tf: Transform2D = IDENTITY, radius_top=None):
        """Vertical cylinder (or cone frustum) with ``n`` (even) sides; caps are quad fans."""
        r1 = radius if radius_top is None else radius_top
        a = np.arange(n + 1) * (2 * np.pi / n)
        cx, cy = center_xy
        ring0 = np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a), np.full(n + 1, z0)], axis=1)
        ring1 = np.stack([cx + r1 * np.cos(a), cy + r1 * np.sin(a), np.full(n + 1, z1)], axis=1)
        side = np.stack([ring0[:-1], ring0[1:], ring1[1:], ring1[:-1]], axis=1)
        self.quads(obj, paint, tf.point(side))
        for ring, z, up in ((ring1, z1, top), (ring0, z0, bottom)):
            if not up:
                continue
            c = np.array([cx, cy, z])
            k = np.arange(0, n, 2)
            fan = np.stack([np.broadcast_to(c, (len(k), 3)), ring[k], ring[k + 1], ring[k + 2]], axis=1)
            if ring is ring0:
                fan = fan[:, ::-1]
            self.quads(obj, paint, tf.point(fan))

    def blob(self, obj, paint, center, radii, n=4, bumpiness=0.15, tf: Transform2D = IDENTITY):
        """A bumpy ellipsoid made from a subdivided cube projected onto a sphere (outward quads)."""
        c = np.asarray(center, dtype=np.float64)
        r = np.asarray(radii, dtype=np.float64)
        waves = self.rng.standard_normal((4, 3)) * 2.5
        phase = self.rng.uniform(0, 2 * np.pi, 4)
        g = np.linspace(-1, 1, n + 1)
        E = np.eye(3)
        out = []
        for ax in range(3):
            for sgn in (1, -1):
                N = sgn * E[ax]
                U = E[(ax + 1) % 3]
                V = np.cross(N, U)
                P = N + g[:, None, None] * U + g[None, :, None] * V
                P /= np.linalg.norm(P, axis=-1, keepdims=True)
                bump = 1 + bumpiness * np.sin(P @ waves.T + phase).mean(axis=-1)
                P = c + P * r * bump[..., None]
                out.append(np.stack([P[:-1, :-1], P[1:, :-1], P[1:, 1:], P[:-1, 1:]], axis=2).reshape(-1, 4, 3))
        self.quads(obj, paint, tf.point(np.concatenate(out)))

    def mark(self) -> tuple[int, int]:
        """A state to come back to with :meth:`rollback`: (quad batches, objects) so far."""
        return len(self._quads), len(self.object_classes)

    def rollback(self, mark: tuple[int, int]) -> None:
        """Drop every quad and object added since :meth:`mark` gave ``mark`` (paints stay registered)."""
        nq, no = mark
        del self._quads[nq:], self._obj[nq:], self._paint[nq:]
        del self.object_classes[no:], self.object_tint[no:], self.object_waves[no:]

    # -- output --------------------------------------------------------------------------------------
    def finish(self):
        """Return ``(vertices (4n, 3) float64, quads (n, 4) int32, face_object (n,) int32, colors (4n, 3) uint8)``."""
        q = np.concatenate(self._quads)
        obj = np.concatenate(self._obj)
        pid = np.concatenate(self._paint)
        n = len(q)
        verts = q.reshape(-1, 3)
        base = np.array([p.rgb for p in self.paints], dtype=np.float64)[pid]
        jit = np.array([p.jitter for p in self.paints])[pid]
        amp = np.array([p.noise for p in self.paints])[pid]
        per = np.array([p.stripes for p in self.paints])[pid]
        alt = np.array([p.stripe_rgb for p in self.paints], dtype=np.float64)[pid]
        tint = np.array(self.object_tint)[obj]
        waves = np.stack(self.object_waves)[obj]  # (n, 3, 4)
        cell = 1.0 + jit * self.rng.standard_normal(n)
        col = np.empty((n, 4, 3))
        for k in range(4):
            p = q[:, k]
            wave = np.sin(np.einsum("nij,nj->ni", waves[:, :, :3], p) + waves[:, :, 3]).mean(axis=1)
            rgb = base.copy()
            striped = per > 0
            if striped.any():
                ph = np.sin(2 * np.pi * (p[:, 0] + p[:, 1] + 0.5 * p[:, 2]) / np.where(striped, per, 1.0))
                rgb = np.where((striped & (ph > 0))[:, None], alt, rgb)
            col[:, k] = rgb * (tint * cell * (1.0 + amp * wave))[:, None]
        colors = np.clip(np.round(col.reshape(-1, 3)), 0, 255).astype(np.uint8)
        faces = np.arange(4 * n, dtype=np.int32).reshape(n, 4)
        return verts, faces, obj, colors
