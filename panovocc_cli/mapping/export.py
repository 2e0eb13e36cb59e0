"""From memory to outputs: the occupancy decision, the (labelled) grid, and the colours of occupied voxels.

Two decision rules (``OccupancyParams.rule``; defaults and reasons: docs/mapping.md):

* ``frequency`` (default): occupied iff ``N / max(O, 1) - lambda_n F / max(O, 1) >= nu``: the share of a
  voxel's valid observations in which a measurement (or strong kernel support) lay in it, less a share
  of those that saw through it;
* ``score`` (the paper's): with the signed score ``g = A / max(N, 1) - lambda_f F / max(O, 1)``,
  occupied iff N > 0 and ``g >= tau_s`` (strong), or ``g >= tau_w`` with ``F / max(O, 1) <= gamma_f``
  (weak support not contradicted by free space).

Either rule can be followed by the **spill thinning** (``OccupancyParams.spill`` > 0, off by default;
:func:`thin_spill`): an occupied voxel in a sheet beside a face neighbour with a much larger support share
``A / max(O, 1)`` (and no occupied voxel on its other side, or a second such neighbour there), whose hits
each brought as much support as the neighbour's, is that neighbour's surface smeared over the face by
pose error, and is not occupied. It reads each voxel's six face neighbours by key (``lookup``), so a
region's decision does not depend on how the memory is sliced.

An unoccupied voxel is free (0) when some frame carved it (F > 0) and unobserved (255) otherwise. The
score g is exported either way (the semantic consolidation uses it).

Labels (:func:`label_occupied`): the occupied set comes from the geometry alone; over it,
``gsc.unaries`` (E/S, mean normal, mean colour), the mapper's signed score ``g`` and
``gsc.consolidate`` give a vocabulary index or -1 (grid label 254).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..classes import class_color
from ..errors import PanovoccError
from ..geometry.lattice import KEY_RANGE, index_to_center, pack_keys, unpack_index, unpack_keys
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from ..semantics.gsc import BLOCK, block_halo, consolidate_blocks, unaries
from .contributors import NORMAL_STEPS, S_SCALE
from .memory import BLOCK as MEMORY_BLOCK
from .memory import FIXED_SCALE, GEOMETRY_NAMES, OFFSET_CHANNEL
from .params import RULES, OccupancyParams
from .psvf.update import NORMAL_UNIT, OFFSET_STEPS

UNCLASSED_COLOR = (160, 160, 160)  # map.ply colour of occupied voxels without a class
UNKNOWN_CLASS = -2  # previous_labels: a voxel the previous grid does not hold as occupied


def signed_score(A, N, F, O) -> tuple[np.ndarray, np.ndarray]:
    """``A / max(N, 1)`` and the free ratio ``F / max(O, 1)`` (float64) from the stored integers (A fixed point)."""
    a = np.asarray(A, np.float64).reshape(-1) / FIXED_SCALE
    n = np.maximum(np.asarray(N, np.float64).reshape(-1), 1.0)
    f = np.asarray(F, np.float64).reshape(-1)
    o = np.maximum(np.asarray(O, np.float64).reshape(-1), 1.0)
    return a / n, f / o


def classify(A, N, F, O, p: OccupancyParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Occupied and free masks (bool) and the score g (float64) of voxels given their channels."""
    if p.rule not in RULES:
        raise PanovoccError(f"unknown occupancy rule {p.rule!r} (expected frequency or score)")
    support, free_ratio = signed_score(A, N, F, O)
    g = support - p.lambda_f * free_ratio
    n = np.asarray(N).reshape(-1)
    has = n > 0
    if p.rule == "score":
        occ = has & ((g >= p.tau_s) | ((g >= p.tau_w) & (free_ratio <= p.gamma_f)))
    else:
        o = np.maximum(np.asarray(O, np.float64).reshape(-1), 1.0)
        occ = has & (n / o - p.lambda_n * free_ratio >= p.nu)
    free = ~occ & (np.asarray(F).reshape(-1) > 0)
    return occ, free, g


FACES = tuple((axis, sign) for axis in range(3) for sign in (1, -1))  # the six face neighbours


def _neighbour_keys(keys: np.ndarray, axis: int, sign: int) -> tuple[np.ndarray, np.ndarray]:
    """Keys (n,) of the face neighbours ``keys + sign e_axis`` and whether each lies on the lattice (the
    keys of those that do not are meaningless)."""
    idx = unpack_keys(keys)
    idx[:, axis] += sign
    ok = np.abs(idx[:, axis]) < KEY_RANGE
    idx[~ok, axis] = 0
    return pack_keys(idx), ok


def _support_share(A, O) -> np.ndarray:
    """``A / max(O, 1)`` (float64, A fixed point): a voxel's kernel support per observing frame."""
    return (np.asarray(A, np.float64).reshape(-1) / FIXED_SCALE) / np.maximum(np.asarray(O, np.float64).reshape(-1), 1.0)


def thin_spill(keys: np.ndarray, channels, occ: np.ndarray, lookup, p: OccupancyParams) -> np.ndarray:
    """The occupied mask of ``keys`` after the spill thinning (docs/mapping.md, step 6).

    With a voxel's support share ``a = A / max(O, 1)`` and support per hit frame ``s = A / max(N, 1)``, an
    occupied voxel v is a spill, and not occupied, when across each axis j != i it has an occupied
    neighbour (it lies in a sheet parallel to the faces normal to axis i) and, along axis i, either

    * (face) its neighbour u = v + d e_i is occupied, ``a_v < spill a_u``, ``s_v >= spill_support s_u``
      and the neighbour on its other side, v - d e_i, is not occupied (free or unobserved); or
    * (between) both v +- e_i are occupied, ``a_v < spill_between min(a)`` and ``s_v >= spill_support
      min(s)`` of the two.

    The support-per-hit test keeps a voxel that a surface only clips (the end of a wall, a tie on a face:
    every hit brings less support) and takes one that whole surface patches fell in, in a minority of the
    frames (pose error). Every test reads the base rule's decisions (:func:`classify`), never thinned
    ones, so the result does not depend on the order or the grouping of the voxels.

    Parameters
    ----------
    keys : (n,) int64 voxel keys; channels : their A, N, F, O ((n, 1) int64)
    occ : (n,) bool, the base rule's decision at ``keys``
    lookup : callable ``keys -> dict`` of A, N, F, O ((m, 1) int64, zeros for a voxel not in the memory)
        at any voxels: the memory read by key
    p : OccupancyParams (``spill`` > 0, ``spill_between``, ``spill_support``)

    Returns
    -------
    (n,) bool, ``occ`` less the spills
    """
    if p.spill <= 0 or not occ.any():
        return occ
    sel = np.flatnonzero(occ)
    kk = np.asarray(keys, np.int64).reshape(-1)[sel]
    share = _support_share(channels["A"], channels["O"])[sel]
    per_hit = signed_score(channels["A"], channels["N"], channels["F"], channels["O"])[0][sel]
    nb = {}
    for axis, sign in FACES:
        nk, ok = _neighbour_keys(kk, axis, sign)
        c = lookup(nk)
        o = classify(c["A"], c["N"], c["F"], c["O"], p)[0]
        nb[axis, sign] = (o & ok, np.where(ok, _support_share(c["A"], c["O"]), 0.0),
                          np.where(ok, signed_score(c["A"], c["N"], c["F"], c["O"])[0], 0.0))
    sheet = [nb[j, 1][0] | nb[j, -1][0] for j in range(3)]  # an occupied neighbour across axis j
    spill = np.zeros(len(sel), bool)
    for axis in range(3):
        across = np.logical_and.reduce([sheet[j] for j in range(3) if j != axis])
        for sign in (1, -1):
            u_occ, u_share, u_hit = nb[axis, sign]
            spill |= (across & u_occ & (share < p.spill * u_share) & (per_hit >= p.spill_support * u_hit)
                      & ~nb[axis, -sign][0])
        (u_occ, u_share, u_hit), (w_occ, w_share, w_hit) = nb[axis, 1], nb[axis, -1]
        spill |= (across & u_occ & w_occ & (share < p.spill_between * np.minimum(u_share, w_share))
                  & (per_hit >= p.spill_support * np.minimum(u_hit, w_hit)))
    out = occ.copy()
    out[sel[spill]] = False
    return out


def _offsets(P) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From channel P ((n, 10) int64): the frames with a measurement m (n,) float64, the mean over those frames
    of the measurements' mean offset from the voxel centre (n, 3) in voxel edges, their mean normal towards
    the camera (n, 3) and the variance over the frames of the mean offset (n, 3) in voxel edges squared
    (zeros where m = 0)."""
    P = np.asarray(P, np.float64).reshape(-1, OFFSET_CHANNEL.width)
    m = P[:, 0]
    d = np.maximum(m, 1.0)[:, None]
    mean = P[:, 1:4] / d
    var = np.maximum(P[:, 7:10] / d - mean * mean, 0.0) / OFFSET_STEPS ** 2
    return m, mean / OFFSET_STEPS, P[:, 4:7] / (d * NORMAL_UNIT), var


def resolve_faces(keys: np.ndarray, channels, occ: np.ndarray, lookup, p: OccupancyParams) -> np.ndarray:
    """The occupied mask of ``keys`` after the face resolution (docs/mapping.md, step 6).

    An occupied voxel v loses to its occupied face neighbour u = v + d e_i when both hold one surface smeared
    over their shared face (by pose error, or depth noise): in each, the measurements' mean normal (turned
    towards the cameras) is within ``resolve_normal`` of axis i, pointing the same way in both (a surface
    seen from one side: a thin wall's two faces, seen from opposite sides, are kept), the mean offset from
    the centre points at the shared face by at least ``resolve_offset`` voxel edges, the two mean positions
    are closer than ``resolve_gap`` times the spread of the frames' mean positions about them (two surfaces a
    centimetre apart, each measured at its own place frame after frame, are kept), and the mean position of
    the pair's measurements (each voxel's mean weighted by its frames with a measurement) lies in u; when v is
    the voxel on the cameras' side (u behind it), that mean must lie past the face by ``resolve_behind``
    standard errors of it (the spread of the frames' positions about it over the root of their number; 0 by
    default): with it a surface a millimetre or two from the face stays on both sides rather than move behind
    itself on the strength of a few frames. Reads
    the base rule's decisions (``occ``), never resolved ones, and the neighbours by key, so a region's
    result does not depend on how the memory is sliced.

    Parameters
    ----------
    keys : (n,) int64; channels : their A, N, F, O and P; occ : (n,) bool, the base rule's decision
    lookup : callable ``(keys, names) -> dict`` of those channels at any voxels (zeros where absent)
    p : OccupancyParams (``resolve``, ``resolve_normal``, ``resolve_offset``, ``resolve_gap``, ``resolve_behind``)

    Returns
    -------
    (n,) bool, ``occ`` less the voxels that lost to a neighbour
    """
    m_v, off_v, nrm_v, var_v = _offsets(channels["P"])
    cand = occ & (m_v > 0)
    if not cand.any():
        return occ
    sel = np.flatnonzero(cand)
    kk = np.asarray(keys, np.int64).reshape(-1)[sel]
    m_v, off_v, nrm_v, var_v = m_v[sel], off_v[sel], nrm_v[sel], var_v[sel]
    lose = np.zeros(len(sel), bool)
    for axis, sign in FACES:
        facing = (np.abs(nrm_v[:, axis]) >= p.resolve_normal) & (sign * off_v[:, axis] >= p.resolve_offset)
        if not facing.any():
            continue
        nk, ok = _neighbour_keys(kk[facing], axis, sign)
        c = lookup(nk, GEOMETRY_NAMES + ("P",))
        u_occ = classify(c["A"], c["N"], c["F"], c["O"], p)[0] & ok
        m_u, off_u, nrm_u, var_u = _offsets(c["P"])
        f = np.flatnonzero(facing)
        same = (u_occ & (m_u > 0) & (np.abs(nrm_u[:, axis]) >= p.resolve_normal)
                & (np.sign(nrm_u[:, axis]) == np.sign(nrm_v[f, axis])) & (-sign * off_u[:, axis] >= p.resolve_offset))
        if p.resolve_gap > 0:  # one surface smeared, not two: the means closer than resolve_gap pooled spreads
            gap = 1.0 + sign * off_u[:, axis] - sign * off_v[f, axis]
            spread = np.sqrt((m_v[f] * var_v[f, axis] + m_u * var_u[:, axis]) / np.maximum(m_v[f] + m_u, 1.0))
            same &= gap <= p.resolve_gap * spread
        # the pair's mean position along the axis, from v's centre, in voxel edges; in u past the face at d/2
        mean = (m_v[f] * off_v[f, axis] + m_u * (sign + off_u[:, axis])) / np.maximum(m_v[f] + m_u, 1.0)
        margin = 0.0
        if p.resolve_behind > 0:  # v on the cameras' side, u behind it: lose only when the mean is surely behind
            front = np.sign(nrm_v[f, axis]) == -sign
            spread2 = (m_v[f] * (var_v[f, axis] + (off_v[f, axis] - mean) ** 2)
                       + m_u * (var_u[:, axis] + (sign + off_u[:, axis] - mean) ** 2)) / np.maximum(m_v[f] + m_u, 1.0)
            margin = np.where(front, p.resolve_behind * np.sqrt(spread2 / np.maximum(m_v[f] + m_u, 1.0)), 0.0)
        lose[f] |= same & (sign * mean > 0.5 + margin)
    out = occ.copy()
    out[sel[lose]] = False
    return out


def decide(keys, channels, p: OccupancyParams, lookup=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`classify` of the voxels ``keys`` (their channels A, N, F, O, and P with ``p.resolve``) followed,
    with ``p.spill > 0``, by :func:`thin_spill` and, with ``p.resolve`` and a channel P, by
    :func:`resolve_faces` (both need ``lookup``; each reads the base rule's decisions, and a voxel either
    takes out is not occupied): occupied and free masks and the score g."""
    occ, free, g = classify(channels["A"], channels["N"], channels["F"], channels["O"], p)
    resolve = p.resolve and "P" in channels
    if p.spill > 0 or resolve:
        if lookup is None:
            raise PanovoccError("the spill thinning and the face resolution need the voxels' neighbours (a lookup "
                                "of the memory by key)")
        kept = thin_spill(keys, channels, occ, lookup, p) if p.spill > 0 else occ
        if resolve:
            kept = kept & resolve_faces(keys, channels, occ, lookup, p)
        free = free | (occ & ~kept & (np.asarray(channels["F"]).reshape(-1) > 0))
        occ = kept
    return occ, free, g


def key_lookup(keys: np.ndarray, channels):
    """:func:`thin_spill`'s and :func:`resolve_faces`' ``lookup`` over sorted ``keys`` and their channels (a dict
    of (n, w) arrays, or a reader with ``at(positions, names)``): ``lookup(q, names=GEOMETRY_NAMES)``, those
    channels at any keys q, zeros where absent."""
    keys = np.asarray(keys, np.int64)

    def lookup(q: np.ndarray, names=GEOMETRY_NAMES) -> dict:
        q = np.asarray(q, np.int64)
        if len(keys) == 0:
            return {n: np.zeros((len(q), OFFSET_CHANNEL.width if n == "P" else 1), np.int64) for n in names}
        pos = np.minimum(np.searchsorted(keys, q), len(keys) - 1)
        found = keys[pos] == q
        c = _geometry(channels, pos, names)
        return {n: np.where(found[:, None], np.asarray(c[n], np.int64), 0) for n in names}

    return lookup


def memory_to_grid(keys: np.ndarray, channels: dict, voxel_size: float, p: OccupancyParams,
                   class_names=("empty",)) -> tuple[Grid, np.ndarray]:
    """Three-state grid over the box of all observed voxels.

    Parameters
    ----------
    keys : (n,) int64 sorted voxel keys; channels : dict with A, N, F, O (n, 1) int64

    Returns
    -------
    grid : Grid, labels 254 occupied / 0 free / 255 unobserved
    occupied_keys : (m,) int64 keys of the occupied voxels (sorted)
    """
    grid, occ_keys, _, _ = _grid_of(keys, channels, voxel_size, p, class_names)
    return grid, occ_keys


CHUNK = 1 << 18  # voxels per slice of the export's per-voxel work (bounds its temporaries)


def _slices(n: int):
    return (slice(a, min(a + CHUNK, n)) for a in range(0, n, CHUNK))


def _grid_of(keys, channels, voxel_size: float, p: OccupancyParams, class_names=("empty",)):
    """:func:`memory_to_grid`'s grid and occupied keys, and the positions (m,) of the occupied voxels in
    ``keys`` with their score g (m,) (:func:`_grid_of_pieces` of one piece)."""
    return _grid_of_pieces(lambda: [(keys, channels, None)], voxel_size, p, class_names,
                           lookup=key_lookup(keys, channels) if needs_neighbours(p) else None)


def _geometry(channels, rows, names=GEOMETRY_NAMES) -> dict:
    """Channels ``names`` (A, N, F, O) at ``rows`` (a slice, or positions) of a dict of (n, w) arrays or a
    reader with ``at(positions, names)``."""
    if hasattr(channels, "at"):
        return channels.at(np.arange(rows.start, rows.stop) if isinstance(rows, slice) else rows, names)
    return {k: channels[k][rows] for k in names}


def decision_names(p: OccupancyParams, channels) -> tuple:
    """The channels the export's decision reads: A, N, F, O, and P when the face resolution is on and the
    memory has it (a map made without the channel exports without the rule)."""
    return GEOMETRY_NAMES + (("P",) if p.resolve and "P" in channels else ())


def needs_neighbours(p: OccupancyParams) -> bool:
    """Whether the decision reads each voxel's face neighbours (the spill thinning, the face resolution)."""
    return p.spill > 0 or p.resolve


def _grid_of_pieces(pieces, voxel_size: float, p: OccupancyParams, class_names=("empty",), lookup=None):
    """The three-state grid of non-zero voxels given in pieces, the occupied voxels' keys (m,), ids (m,)
    int64 and score g (m,).

    ``pieces()`` yields ``(keys, channels, ids)`` in key order: sorted keys (n,), their channels (a dict,
    or a reader with ``at(positions, names)``) and an id per voxel that the caller's reader of the occupied
    voxels understands (None: the position in the concatenated keys). Called twice (the grid's box, then
    the grid), each piece in slices of :data:`CHUNK` voxels: the temporaries beside the grid are a slice's,
    the occupied voxels' keys, ids and g, and the states the first pass decided (2 bits a voxel, packed;
    the second pass reads only the keys). The states and g are the same as one :func:`decide` call's.
    ``lookup``: the memory's geometry channels at any keys (:func:`thin_spill`; needed with ``p.spill > 0``).
    """
    g_occ, occ_keys, occ_ids = [], [], []
    states = []  # each slice's occupied and free flags, packed (2 bits a voxel): the second pass decides nothing
    i0 = np.full(3, np.iinfo(np.int64).max, np.int64)
    i1 = np.full(3, np.iinfo(np.int64).min, np.int64)
    offset = 0
    for keys, channels, ids in pieces():
        names = decision_names(p, channels)
        for sl in _slices(len(keys)):  # a memory's channels are read a slice at a time (never all at once)
            c = _geometry(channels, sl, names)
            occ, free, g = decide(keys[sl], c, p, lookup)
            g_occ.append(g[occ])
            occ_keys.append(keys[sl][occ])
            occ_ids.append(np.flatnonzero(occ) + (offset + sl.start) if ids is None else ids[sl][occ])
            states.append((np.packbits(occ), np.packbits(free)))
            kept = keys[sl][occ | free]
            if len(kept):  # the box: each axis's index apart (1-D reductions, no (n, 3) array)
                ijk = unpack_index(kept)
                i0 = np.minimum(i0, [v.min() for v in ijk])
                i1 = np.maximum(i1, [v.max() for v in ijk])
            del c, occ, free, g, kept
        offset += len(keys)
    cat = (lambda parts, dt: np.concatenate(parts) if parts else np.zeros(0, dt))
    g_occ, occ_keys, occ_ids = cat(g_occ, np.float64), cat(occ_keys, np.int64), cat(occ_ids, np.int64)
    if np.any(i0 > i1):  # nothing occupied or free
        labels = np.full((1, 1, 1), UNKNOWN, np.uint8)
        return (Grid(labels, index_to_center(np.zeros(3, np.int64), voxel_size), voxel_size, list(class_names)),
                occ_keys, occ_ids, g_occ)
    labels = np.full(tuple(i1 - i0 + 1), UNKNOWN, np.uint8)
    st = iter(states)
    for keys, _, _ in pieces():  # the same pieces and slices: the first pass's flags, in order
        for sl in _slices(len(keys)):
            n = sl.stop - sl.start
            po, pf = next(st, (None, None))
            if po is None or len(po) != (n + 7) // 8:
                raise RuntimeError("_grid_of_pieces: the pieces changed between its two passes")
            occ, free = np.unpackbits(po, count=n).view(bool), np.unpackbits(pf, count=n).view(bool)
            kept = occ | free
            i, j, k = unpack_index(keys[sl][kept])
            labels[i - i0[0], j - i0[1], k - i0[2]] = np.where(occ[kept], OCCUPIED_UNKNOWN_CLASS, EMPTY).astype(np.uint8)
            del occ, free
    if next(st, None) is not None:
        raise RuntimeError("_grid_of_pieces: the pieces changed between its two passes")
    grid = Grid(labels, index_to_center(i0, voxel_size), voxel_size, list(class_names))
    return grid, occ_keys, occ_ids, g_occ


def height_colors(z: np.ndarray, z_range: tuple | None = None) -> np.ndarray:
    """(n, 3) uint8 colours of heights z (n,) metres: a blue-green-yellow-red ramp over their range (or over
    ``z_range`` = (lowest, highest), when z is a part of the points)."""
    z = np.asarray(z, np.float64)
    if z_range is None and len(z):
        z_range = (z.min(), z.max())
    t = (z - z_range[0]) / max(float(z_range[1] - z_range[0]), 1e-9) if len(z) else z
    stops = np.array([[49, 54, 149], [69, 170, 110], [250, 220, 60], [215, 48, 39]], np.float64)
    x = t * (len(stops) - 1)
    k = np.clip(np.floor(x).astype(int), 0, len(stops) - 2)
    f = (x - k)[:, None]
    return np.rint(stops[k] * (1 - f) + stops[k + 1] * f).astype(np.uint8)


class OccupiedChannels(Mapping):
    """A memory's channels at its occupied voxels (name -> (m, width) int64, rows in ``occupied_keys``
    order), each read from the memory when first asked for, or a block of rows at a time (:meth:`rows`):
    a large map's export never holds every channel of every occupied voxel at once."""

    def __init__(self, channels, pos: np.ndarray):
        self._channels, self._pos, self._cache = channels, pos, {}

    def rows(self, sl: slice, names) -> dict:
        """Channels ``names`` at the occupied voxels ``sl`` (a slice of the rows)."""
        p = self._pos[sl]
        if hasattr(self._channels, "at"):
            return self._channels.at(p, names)
        return {k: self._channels[k][p] for k in names}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cache:
            if name not in self._channels:
                raise KeyError(name)
            # a copy: the memory reads a group of channels into one array and hands out column views
            self._cache[name] = np.ascontiguousarray(self.rows(slice(None), [name])[name])
        return self._cache[name]

    def __contains__(self, name) -> bool:  # without reading the channel
        return name in self._channels

    def __iter__(self):
        return iter(self._channels)

    def __len__(self) -> int:
        return len(self._channels)


@dataclass
class MapExport:
    """What the memory says at one moment: the grid and, for the point cloud, its occupied voxels.

    grid : Grid, labels 1..C a vocabulary class (or 254 without class), 0 free, 255 unobserved;
        ``class_names = ["empty"] + vocabulary`` (``["empty"]`` for a geometry-only map)
    occupied_keys : (m,) int64 sorted keys of the occupied voxels, relative to ``origin_index``
    labels : (m,) int64 vocabulary index per occupied voxel (-1 = no class), or None without semantics
    channels : mapping name -> (m, width) int64, the memory channels at the occupied voxels
        (:class:`OccupiedChannels`: each read when first asked for)
    origin_index : (3,) int64, the map's local origin on the world lattice (the grid is in world placement)
    """

    grid: Grid
    occupied_keys: np.ndarray
    labels: np.ndarray | None
    channels: dict
    origin_index: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))

    def centres(self, rows=None) -> np.ndarray:
        """World centres (m, 3) float64 metres of the occupied voxels (or of ``rows`` of them)."""
        keys = self.occupied_keys if rows is None else self.occupied_keys[rows]
        return index_to_center(unpack_keys(keys) + self.origin_index, self.grid.voxel_size)

    def summary(self) -> dict:
        """Counts: occupied and free voxels, and (with semantics) occupied voxels with a class."""
        out = {"occupied": int(len(self.occupied_keys)), "free": int((self.grid.labels == EMPTY).sum())}
        if self.labels is not None:
            out["classed"] = int((self.labels >= 0).sum())
        return out


SEMANTIC_INPUTS = ("E", "S", "normal_sum", "rgb_sum", "count")
"""The stored channels GSC's inputs are made of (:func:`gsc_inputs`)."""

UNARY_ROWS = 8192
"""Rows :func:`gsc_inputs` turns into unaries at a time: the float64 temporaries (several (n, C) arrays) are a
chunk's, not a GSC cube's (a cube of the house held 46 k rows: 13 MB of them at the export's peak, docs/mapping.md
"The house's peak, fifth pass")."""


def gsc_inputs(channels, g: np.ndarray, rows: np.ndarray) -> tuple:
    """:func:`~panovocc_cli.semantics.gsc.consolidate`'s inputs ``(p, S, g, normals, colors)`` of the occupied
    voxels at positions ``rows`` (sorted) from their stored channels (:class:`OccupiedChannels`) and their
    score ``g`` (all occupied voxels'): per-voxel values, the same whichever rows are read together."""
    c = channels.rows(rows, SEMANTIC_INPUTS)
    S = c["S"][:, 0] / S_SCALE
    n, C = c["E"].shape
    p, normals, colors = np.empty((n, C), np.float32), np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    for a in range(0, n, UNARY_ROWS):  # row by row the same values: only the float64 temporaries are a chunk's
        r = slice(a, a + UNARY_ROWS)
        p[r], normals[r], colors[r] = unaries(c["E"][r] / S_SCALE, S[r], c["normal_sum"][r] / NORMAL_STEPS,
                                              c["rgb_sum"][r], c["count"][r, 0])
    return p, S, np.asarray(g, np.float64)[rows], normals, colors


def label_occupied(occupied_keys: np.ndarray, channels: dict, g: np.ndarray, params, *, block: int | None = None,
                   previous: np.ndarray | None = None, changed_keys: np.ndarray | None = None,
                   changed_blocks: np.ndarray | None = None, progress=None) -> np.ndarray:
    """Vocabulary index of each occupied voxel, or -1 (no class; exported as 254).

    Labelled a cube of ``block`` voxels a side at a time (:func:`~panovocc_cli.semantics.gsc.
    consolidate_blocks`: the same labels as the whole map at once, whatever ``block``, default
    :data:`~panovocc_cli.semantics.gsc.BLOCK`): the working set is a cube's and its halo's, not the map's.

    Parameters
    ----------
    occupied_keys : (n,) int64 strictly increasing voxel keys (lattice.pack_keys)
    channels : the occupied voxels' stored channels, rows aligned with ``occupied_keys`` (a dict, or
        :class:`OccupiedChannels`, read a cube at a time): E (n, C), S (n, 1), normal_sum (n, 3),
        rgb_sum (n, 3), count (n, 1) int64 (the integer channels of :mod:`.contributors`)
    g : (n,) float64, the mapper's signed score (per-frame support units, ~0..1 on surfaces)
    params : object with ``use_gsc`` and ``gsc`` (``MapperConfig`` or ``SemanticParams``)
    previous : (n,) int64, optional, the labels of an export of the same memory before the voxels
        ``changed_keys`` and those of ``changed_blocks`` changed (any channel; a voxel that became or stopped
        being occupied is one): only the voxels within the GSC's reach of a changed one are labelled again,
        from those within twice its reach (:func:`relabel_region`), the others keep ``previous``; the
        result equals a full labelling bit for bit
    changed_keys : (k,) int64 voxel keys; changed_blocks : (m, 3) int64 memory block indices (voxel index //
        :data:`~.memory.BLOCK`), every voxel of which may have changed; either or both, with ``previous``
    progress : callable ``(voxels done)``, optional

    Returns
    -------
    labels : (n,) int64 in -1..C-1
    """
    n = len(occupied_keys)
    block = BLOCK if block is None else int(block)
    if (previous is None) != (changed_keys is None and changed_blocks is None):
        raise PanovoccError("label_occupied: previous and the changed voxels (changed_keys, changed_blocks) go together")
    if n == 0:
        return np.zeros(0, np.int64)
    if not isinstance(channels, OccupiedChannels):  # a dict of the occupied rows
        channels = OccupiedChannels(channels, np.arange(n))
    region = labels = None
    if previous is not None:
        labels = np.array(previous, np.int64)
        if labels.shape != (n,):
            raise PanovoccError(f"previous labels {labels.shape} must be ({n},)")
        region = relabel_region(np.asarray(occupied_keys, np.int64), changed_keys, changed_blocks,
                                block_halo(params.use_gsc, params.gsc))
    return consolidate_blocks(np.asarray(occupied_keys, np.int64), lambda rows: gsc_inputs(channels, g, rows),
                              use_gsc=params.use_gsc, params=params.gsc, block=block, labels=labels, region=region,
                              progress=progress)


def _dilated_blocks(blocks: np.ndarray, r: int) -> np.ndarray:
    """Packed keys (sorted, unique) of the blocks within Chebyshev distance ``r`` of ``blocks`` ((m, 3) int64
    block indices): one axis at a time."""
    b = np.unique(pack_keys(blocks)) if len(blocks) else np.zeros(0, np.int64)
    for axis in range(3):
        if not len(b) or r <= 0:
            break
        idx = unpack_keys(b)
        grown = np.repeat(idx[:, None, :], 2 * r + 1, axis=1)
        grown[:, :, axis] += np.arange(-r, r + 1)
        b = np.unique(pack_keys(grown.reshape(-1, 3)))
    return b


def relabel_region(keys: np.ndarray, changed_keys, changed_blocks, halo: int) -> np.ndarray:
    """Which occupied voxels an incremental export labels again (2) or only reads (1), and which it keeps (0).

    A voxel's label depends on nothing farther than ``halo`` voxels along each axis
    (:func:`~panovocc_cli.semantics.gsc.block_halo`), so only voxels within ``halo`` of a changed voxel (one
    whose channels or occupancy changed) can change label, and labelling them needs the voxels within
    ``halo`` of those. Both sets are taken whole blocks of :data:`~.memory.BLOCK` voxels at a time around
    the changed voxels' blocks (a superset, so exact): the blocks within ``(halo + 7) // 8`` of a changed
    block are labelled again, those within twice that are read. Cost: the GSC over the changed surfaces'
    neighbourhoods, not over every cube that one reaches.

    Parameters
    ----------
    keys : (n,) int64 the occupied voxels' keys
    changed_keys : (k,) int64 voxel keys or None; changed_blocks : (m, 3) int64 block indices or None
    halo : int, voxels

    Returns
    -------
    (n,) uint8 in 0..2
    """
    parts = [np.zeros((0, 3), np.int64)]
    if changed_keys is not None and len(changed_keys):
        parts.append(unpack_keys(np.unique(np.asarray(changed_keys, np.int64))) // MEMORY_BLOCK)
    if changed_blocks is not None:
        parts.append(np.asarray(changed_blocks, np.int64).reshape(-1, 3))
    blocks = np.concatenate(parts)
    r1 = (int(halo) + MEMORY_BLOCK - 1) // MEMORY_BLOCK
    r2 = 2 * r1
    near, reach = _dilated_blocks(blocks, r1), _dilated_blocks(blocks, r2)
    region = np.zeros(len(keys), np.uint8)
    for sl in _slices(len(keys)):
        kb = _key_blocks(keys[sl])
        for b in (reach, near):  # near lies within reach: 2 near, 1 reach only
            region[sl] += _sorted_isin(kb, b)
    return region


def apply_labels(grid: Grid, occupied_keys: np.ndarray, labels: np.ndarray, vocab: Sequence[str], *,
                 in_place: bool = False) -> Grid:
    """Write class labels into a three-state grid: occupied voxel -> 1 + label (254 where -1).

    The grid's class names become ``["empty"] + vocab``; free (0) and unobserved (255) voxels stay.
    ``in_place``: into ``grid.labels`` itself (an export's own grid: no second grid at once). Written a
    slice of :data:`CHUNK` voxels at a time.
    """
    out = grid.labels if in_place else grid.labels.copy()
    lab = np.asarray(labels, np.int64)
    for sl in _slices(len(occupied_keys)):
        local = unpack_keys(occupied_keys[sl]) - grid.index0
        out[tuple(local.T)] = np.where(lab[sl] >= 0, lab[sl] + 1, OCCUPIED_UNKNOWN_CLASS).astype(np.uint8)
    return Grid(out, grid.origin, grid.voxel_size, ["empty"] + list(vocab))


def class_colors(labels: np.ndarray, vocab: Sequence[str]) -> np.ndarray:
    """(n, 3) uint8 colours: :func:`classes.class_color` of each label, grey for -1."""
    table = np.array([class_color(c) for c in vocab] + [UNCLASSED_COLOR], np.uint8).reshape(-1, 3)
    lab = np.asarray(labels, np.int64)
    return table[np.where(lab >= 0, lab, len(vocab))]


def export_memory(keys: np.ndarray, channels: dict, voxel_size: float, occupancy: OccupancyParams,
                  vocab=(), semantic=None, origin_index=(0, 0, 0), *, previous: Grid | None = None,
                  changed_keys: np.ndarray | None = None, changed_blocks: np.ndarray | None = None, pieces=None,
                  reader=None, lookup=None, block: int | None = None) -> MapExport:
    """The labelled grid of a memory's non-zero voxels.

    The occupied set comes from the geometry alone (:func:`memory_to_grid`); with a vocabulary and
    semantic channels, each occupied voxel is labelled by :func:`label_occupied` (GSC or raw
    argmax, bounded nearest-evidence transfer, a cube of the key space at a time), -1 -> 254.

    Parameters
    ----------
    keys : (n,) int64 sorted voxel keys; channels : dict name -> (n, width) int64 (``VoxelMemory.nonzero``)
    voxel_size : float, metres
    occupancy : OccupancyParams
    vocab : sequence of str, the vocabulary (empty = geometry only)
    semantic : object with ``use_gsc`` and ``gsc`` (``MapperConfig``), needed with a vocabulary
    origin_index : (3,) int64, the lattice index the keys are relative to (the map's local origin); the
        grid is placed in the world by it
    previous : Grid, optional, this export's grid before the voxels ``changed_keys`` ((k,) int64, keys
        relative to ``origin_index``) and every voxel of the blocks ``changed_blocks`` ((m, 3) int64 memory
        block indices, ``VoxelMemory.changed_blocks``) changed: an incremental export, which labels again only
        the voxels within the GSC's reach of a changed voxel (or of an occupied voxel ``previous`` does not
        hold as occupied; :func:`relabel_region`) and takes the other labels from ``previous``; the same
        result, bit for bit, as without it
    pieces, reader : instead of ``keys`` and ``channels`` (None then): the non-zero voxels a slab at a
        time (:func:`_grid_of_pieces`, e.g. ``VoxelMemory.nonzero_slabs``) and ``reader(ids)``, the
        occupied voxels' channels (:class:`OccupiedChannels`) from their ids: an export that never holds
        every non-zero voxel's key at once
    lookup : with ``pieces``, the memory's geometry channels at any keys (``VoxelMemory.gather``): the spill
        thinning's neighbours (:func:`thin_spill`; needed with ``occupancy.spill > 0``)
    block : the GSC cube side in voxels (:func:`label_occupied`; default :data:`~..semantics.gsc.BLOCK`): the
        same labels whatever it is; a larger cube consolidates fewer halo voxels twice but holds more at once
    """
    if pieces is None:
        pieces = (lambda: [(keys, channels, None)])
        reader = (lambda ids: OccupiedChannels(channels, ids))
        lookup = key_lookup(keys, channels) if needs_neighbours(occupancy) else None
    grid, occ_keys, ids, g = _grid_of_pieces(pieces, voxel_size, occupancy, lookup=lookup)
    # a memory's channels are read at the occupied voxels only, and each when it is needed
    sub = reader(ids)
    del ids
    labels = None
    oi = np.asarray(origin_index, np.int64).reshape(3)
    if len(vocab) and "E" in sub:
        before = changed = None
        if previous is not None and _same_classes(previous, voxel_size, vocab):
            if changed_keys is None and changed_blocks is None:
                raise PanovoccError("an incremental export needs the changed voxels' keys with the previous grid")
            before = previous_labels(previous, occ_keys, oi)
            # A label depends on the occupied set and the occupied voxels' channels only: what changed for
            # the labels is the voxels that started or stopped being occupied (read from the two exports, so
            # a rule that reads face neighbours needs no margin) and the changed voxels and blocks that hold
            # an occupied voxel now or before (a block only carved through changes no label).
            was = _occupied_keys(previous, oi)
            stopped = was[~_sorted_isin(was, occ_keys)]
            changed = np.concatenate([np.zeros(0, np.int64) if changed_keys is None else
                                      np.asarray(changed_keys, np.int64).reshape(-1),
                                      occ_keys[before == UNKNOWN_CLASS], stopped])
            if changed_blocks is not None:
                held = np.unique(np.concatenate([_block_keys(occ_keys), _block_keys(was)]))
                changed_blocks = np.asarray(changed_blocks, np.int64).reshape(-1, 3)
                changed_blocks = changed_blocks[_sorted_isin(pack_keys(changed_blocks), held)]
            del was, stopped
        labels = label_occupied(occ_keys, sub, g, semantic, block=block, previous=before, changed_keys=changed,
                                changed_blocks=changed_blocks if before is not None else None)
        grid = apply_labels(grid, occ_keys, labels, vocab, in_place=True)
    if np.any(oi != 0):  # the grid was built on the local keys: place it in the world
        grid = Grid(grid.labels, index_to_center(grid.index0 + oi, voxel_size), voxel_size, grid.class_names)
    return MapExport(grid, occ_keys, labels, sub, oi)


def _same_classes(grid: Grid, voxel_size: float, vocab) -> bool:
    """Whether ``grid`` can hold this export's labels: the same voxel size and class names."""
    return bool(np.isclose(grid.voxel_size, voxel_size)) and list(grid.class_names) == ["empty"] + list(vocab)


def _occupied_keys(grid: Grid, origin_index) -> np.ndarray:
    """Keys (m,) int64, sorted, relative to ``origin_index``, of the voxels a labelled grid holds as occupied."""
    out = []
    for i in range(0, grid.labels.shape[0], 64):  # a slab of the grid at a time
        sl = grid.labels[i:i + 64]
        idx = np.stack(np.nonzero((sl >= 1) & (sl <= OCCUPIED_UNKNOWN_CLASS)), axis=1).astype(np.int64)
        out.append(pack_keys(idx + grid.index0 + [i, 0, 0] - np.asarray(origin_index, np.int64)))
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _sorted_isin(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.isin(a, b)`` for ``b`` sorted (int64)."""
    if not len(b):
        return np.zeros(len(a), bool)
    pos = np.minimum(np.searchsorted(b, a), len(b) - 1)
    return b[pos] == a


def _key_blocks(keys: np.ndarray) -> np.ndarray:
    """The packed memory-block index (voxel index // :data:`~.memory.BLOCK`) of each voxel key, (n,) int64."""
    return np.concatenate([pack_keys(unpack_keys(keys[sl]) // MEMORY_BLOCK) for sl in _slices(len(keys))]
                          + [np.zeros(0, np.int64)])


def _block_keys(keys: np.ndarray) -> np.ndarray:
    """Packed memory-block indices of voxel ``keys`` (:func:`_key_blocks`), unique, sorted."""
    return np.unique(_key_blocks(keys))


def previous_labels(grid: Grid, occupied_keys: np.ndarray, origin_index) -> np.ndarray:
    """Labels (m,) int64 of the voxels ``occupied_keys`` (relative to ``origin_index``) in a labelled grid:
    its class - 1, -1 for 254 (occupied without class), :data:`UNKNOWN_CLASS` where the grid does not hold
    the voxel as occupied (outside it, free or unobserved). A slice at a time."""
    out = np.empty(len(occupied_keys), np.int64)
    shape = np.asarray(grid.labels.shape)
    for sl in _slices(len(occupied_keys)):
        local = unpack_keys(occupied_keys[sl]) + np.asarray(origin_index, np.int64) - grid.index0
        inside = np.all((local >= 0) & (local < shape), axis=1)
        v = np.full(len(local), UNKNOWN, np.int64)
        v[inside] = grid.labels[tuple(local[inside].T)]
        out[sl] = np.where((v >= 1) & (v < OCCUPIED_UNKNOWN_CLASS), v - 1,
                           np.where(v == OCCUPIED_UNKNOWN_CLASS, -1, UNKNOWN_CLASS))
    return out


def point_colors(ex: MapExport, voxel_size: float, color: str, vocab=(), rows=slice(None),
                 z_range: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centres (m, 3) float64 metres (world) and colours (m, 3) uint8 of the occupied voxels (or of ``rows``
    of them; heights are coloured over ``z_range``, the whole map's from :func:`point_chunks`).

    color : ``class`` (class colours, grey for no class), ``rgb`` (mean pixel colour, grey where no pixel
        fell in the voxel) or ``height``; ``class`` / ``rgb`` fall back to height without semantic channels.
    """
    pts = index_to_center(unpack_keys(ex.occupied_keys[rows]) + ex.origin_index, voxel_size)
    if color == "class" and ex.labels is not None:
        cols = class_colors(ex.labels[rows], vocab)
    elif color == "rgb" and "rgb_sum" in ex.channels:
        ch = ex.channels
        c = ch.rows(rows, ("count", "rgb_sum")) if hasattr(ch, "rows") else {k: ch[k][rows] for k in ("count", "rgb_sum")}
        cnt = c["count"][:, :1]
        rgb = np.clip(np.rint(c["rgb_sum"] / np.maximum(cnt, 1)), 0, 255).astype(np.uint8)
        cols = np.where(cnt > 0, rgb, np.array(UNCLASSED_COLOR, np.uint8))
    else:
        cols = height_colors(pts[:, 2], z_range)
    return pts, cols


def point_chunks(ex: MapExport, voxel_size: float, color: str, vocab=()):
    """:func:`point_colors` of all occupied voxels a slice of :data:`CHUNK` at a time (the same values:
    heights coloured over the whole map's range), for a point cloud written without its whole arrays."""
    n = len(ex.occupied_keys)
    z_range = None
    if n:
        lo, hi = np.iinfo(np.int64).max, np.iinfo(np.int64).min
        for sl in _slices(n):
            z = unpack_index(ex.occupied_keys[sl])[2]
            lo, hi = min(lo, int(z.min())), max(hi, int(z.max()))
        z_range = tuple(index_to_center(np.array([lo, hi]) + ex.origin_index[2], voxel_size))
    for sl in _slices(n):
        yield point_colors(ex, voxel_size, color, vocab, sl, z_range)
