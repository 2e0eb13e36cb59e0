"""The persistent voxel memory: additive integer channels in spatially hashed 8^3 blocks.

A frame's contribution is a sparse :class:`Delta`: sorted unique int64 voxel keys
(:func:`panovocc_cli.geometry.lattice.pack_keys`) and named integer channel arrays. The memory is
the sum of the retained deltas. Integer addition is exact and order-independent, so subtracting a
delta and adding it back leaves the memory bit-identical (the reversible persistent update, RPU).

Channels are generic: each has a name, a width (columns) and a kind. ``"fixed"`` channels hold float
quantities as ``round(value * FIXED_SCALE)`` int64 (fixed point, 2^-16 resolution); ``"int"`` channels
hold exact counts. Geometry uses A (fixed), N, F, O (int); the semantic stage adds its own channels
(E, S, rgb_sum, normal_sum, count) through the same mechanism.

Storage: a block key (the voxel index divided by 8, packed like a voxel key) maps to a block slot
through an open-addressing hash table compiled with numba; each slot holds a dense (512, C) int64
array of all channels side by side. Saved memories list only the non-zero voxels in key order, so two
memories with equal sums have equal bytes whatever their history.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numba as nb
import numpy as np

from ..errors import PanovoccError

FIXED_SCALE = 2 ** 16  # fixed-point scale of "fixed" channels: value = stored / FIXED_SCALE
BLOCK = 8  # voxels per block edge
BLOCK_VOXELS = BLOCK ** 3
_EMPTY = np.int64(-1)
INITIAL_BYTES = 256 * 2 ** 20  # initial block storage of a memory (zeros: pages cost only once written; grows by doubling)


@dataclass(frozen=True)
class ChannelSpec:
    """One memory channel: ``name``, ``width`` (columns per voxel), ``kind`` ``"fixed"`` or ``"int"``."""

    name: str
    width: int = 1
    kind: str = "int"

    def __post_init__(self):
        if self.kind not in ("fixed", "int"):
            raise ValueError(f"channel {self.name}: kind must be 'fixed' or 'int', got {self.kind!r}")
        if self.width < 1:
            raise ValueError(f"channel {self.name}: width must be >= 1")


GEOMETRY_CHANNELS = (
    ChannelSpec("A", 1, "fixed"),  # surface support (sum of kernel weights)
    ChannelSpec("N", 1, "int"),  # frames that gave support
    ChannelSpec("F", 1, "int"),  # free-space evidence (frames that saw through the voxel)
    ChannelSpec("O", 1, "int"),  # valid depth comparisons
)


def quantize(values, kind: str) -> np.ndarray:
    """Float values -> int64 storage: ``round(v * FIXED_SCALE)`` for ``"fixed"``, ``round(v)`` for ``"int"``."""
    v = np.asarray(values, dtype=np.float64)
    if kind == "fixed":
        v = v * FIXED_SCALE
    return np.rint(v).astype(np.int64)


@dataclass
class Delta:
    """One frame's sparse contribution.

    keys : (n,) int64, sorted, unique voxel keys
    channels : dict name -> (n, width) int64 (only channels the contributor produces)
    """

    keys: np.ndarray
    channels: dict

    def __post_init__(self):
        self.keys = np.asarray(self.keys, dtype=np.int64)
        self.channels = {k: _rows(v, len(self.keys)) for k, v in self.channels.items()}

    def __len__(self) -> int:
        return len(self.keys)

    def check(self) -> "Delta":
        if self.keys.ndim != 1 or (len(self.keys) > 1 and np.any(np.diff(self.keys) <= 0)):
            raise ValueError("delta keys must be a sorted unique 1-D int64 array")
        return self


def _rows(values, n: int) -> np.ndarray:
    """A channel as (n, width) int64 (an (n,) array is one column; an empty delta keeps its width)."""
    a = np.asarray(values, dtype=np.int64)
    if a.ndim == 2 and a.shape[0] == n:
        return a
    if n == 0 and a.size == 0:
        return a.reshape(0, a.shape[-1] if a.ndim == 2 else 1)
    return a.reshape(n, -1)


@dataclass
class FrameDelta:
    """One frame's contribution as its contributors made it: one :class:`Delta` per contributor (the
    geometry's, the semantics'), disjoint channel names, each over its own keys.

    Kept apart, not merged over the union of their keys: the semantic channels (E is C wide) touch only
    the voxels pixels fell in, a tenth of the geometry's free-space rows, so a merged delta would be
    mostly zeros to allocate, add, scan and compress (:func:`merge_deltas` gives that single Delta).
    """

    parts: tuple

    def __post_init__(self):
        self.parts = tuple(p for p in self.parts if p is not None and len(p) and p.channels)
        _check_disjoint(self.parts)

    def __len__(self) -> int:
        """Rows over all parts (0: the frame changes nothing)."""
        return sum(len(p) for p in self.parts)



def _check_disjoint(parts: Sequence[Delta]) -> None:
    """Contributors' deltas must not share a channel name (ValueError naming it)."""
    names = [name for p in parts for name in p.channels]
    if len(set(names)) < len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"channel {dup} produced by two contributors")


def merge_deltas(parts: Sequence[Delta]) -> Delta:
    """Combine contributors' deltas (disjoint channel names) into one over the union of their keys."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return Delta(np.zeros(0, np.int64), {})
    if len(parts) == 1:
        return parts[0]
    keys = np.concatenate([p.keys for p in parts])
    keys.sort(kind="stable")  # each part's keys are sorted: a linear merge of runs (np.unique hashes, ~20x slower)
    if len(keys) > 1:
        keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))]
    _check_disjoint(parts)
    # every channel a column slice of one (n, total width) matrix: VoxelMemory.add takes it without a copy
    full = np.zeros((len(keys), sum(a.shape[1] for p in parts for a in p.channels.values())), np.int64)
    out = {}
    c0 = 0
    for p in parts:
        pos = np.searchsorted(keys, p.keys)
        for name, arr in p.channels.items():
            block = full[:, c0:c0 + arr.shape[1]]
            block[pos] = arr
            out[name] = block
            c0 += arr.shape[1]
    return Delta(keys, out)


# ---------------------------------------------------------------------------------------------
# numba kernels: block hash table and scatter-add


@nb.njit(cache=True)
def _hash64(k):
    # splitmix64 finaliser; works on int64 with wrap-around
    x = np.uint64(k)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    x = x ^ (x >> np.uint64(31))
    return x


@nb.njit(cache=True)
def _lookup_insert(table_keys, table_slots, bkey, next_slot):
    """Return (slot, inserted); -1 slot when the table has no room left for a new block."""
    mask = np.uint64(table_keys.shape[0] - 1)
    h = _hash64(bkey) & mask
    while True:
        k = table_keys[h]
        if k == bkey:
            return table_slots[h], False
        if k == -1:
            table_keys[h] = bkey
            table_slots[h] = next_slot
            return next_slot, True
        h = (h + np.uint64(1)) & mask


@nb.njit(cache=True)
def _block_key_and_offset(key):
    # key layout (lattice.pack_keys): 21 bits per axis, offset 2^20; block index = floor(index / 8)
    off = 1 << 20
    m = (1 << 21) - 1
    i = ((key >> 42) & m) - off
    j = ((key >> 21) & m) - off
    z = (key & m) - off
    bi = (i >> 3) + off
    bj = (j >> 3) + off
    bz = (z >> 3) + off
    bkey = (bi << 42) | (bj << 21) | bz
    o = ((i & 7) << 6) | ((j & 7) << 3) | (z & 7)
    return bkey, o


@nb.njit(cache=True)
def _find(table_keys, table_slots, bkey):
    """Slot of block ``bkey``, -1 when absent."""
    mask = np.uint64(table_keys.shape[0] - 1)
    h = _hash64(bkey) & mask
    while True:
        k = table_keys[h]
        if k == bkey:
            return table_slots[h]
        if k == -1:
            return -1
        h = (h + np.uint64(1)) & mask


@nb.njit(cache=True)
def _scatter_add(table_keys, table_slots, block_keys, data, n_blocks, keys, vals, cols, sign, start):
    """Add ``sign * vals[:, c]`` into column ``cols[c]`` of ``data`` at ``keys``; returns (index reached,
    n_blocks). ``cols[c] < 0`` skips column c of ``vals``.

    Stops early (index < len(keys)) when the hash table would pass half full or the block storage is
    full, so the caller can grow them and call again from there. Block slots are remembered in a small
    direct-mapped cache indexed by the block's low (j, k) bits: keys in lattice order revisit the same
    few dozen blocks row after row, so the hash table is probed about once per block and frame.
    """
    cap_table = table_keys.shape[0]
    cap_data = data.shape[0]
    nc = cols.shape[0]
    run0 = cols[0]
    for c in range(nc):
        if cols[c] != cols[0] + c:
            run0 = -1
    cache_keys = np.full(64, -1, np.int64)
    cache_slots = np.zeros(64, np.int64)
    for n in range(start, keys.shape[0]):
        bkey, o = _block_key_and_offset(keys[n])
        e = (bkey & 7) | ((bkey >> 18) & 56)  # low 3 bits of the block's k and j indices
        if cache_keys[e] == bkey:
            slot = cache_slots[e]
        else:
            if n_blocks >= cap_data or 2 * (n_blocks + 1) > cap_table:
                slot = _find(table_keys, table_slots, bkey)  # might need a new block: look, do not insert
                if slot < 0:
                    return n, n_blocks
            else:
                slot, ins = _lookup_insert(table_keys, table_slots, bkey, n_blocks)
                if ins:
                    block_keys[n_blocks] = bkey
                    n_blocks += 1
            cache_keys[e] = bkey
            cache_slots[e] = slot
        if run0 >= 0:  # the columns map to one run of memory columns
            for c in range(nc):
                data[slot, o, run0 + c] += sign * vals[n, c]
        else:
            for c in range(nc):
                if cols[c] >= 0:
                    data[slot, o, cols[c]] += sign * vals[n, c]
    return keys.shape[0], n_blocks


@nb.njit(cache=True)
def _gather(table_keys, table_slots, data, keys, out):
    """out[n] = data at keys[n] (zeros for voxels in no block)."""
    mask = np.uint64(table_keys.shape[0] - 1)
    for n in range(keys.shape[0]):
        bkey, o = _block_key_and_offset(keys[n])
        h = _hash64(bkey) & mask
        while True:
            k = table_keys[h]
            if k == bkey:
                s = table_slots[h]
                for c in range(data.shape[2]):
                    out[n, c] = data[s, o, c]
                break
            if k == -1:
                break
            h = (h + np.uint64(1)) & mask


@nb.njit(cache=True)
def _rehash(block_keys, n_blocks, cap):
    tk = np.full(cap, -1, np.int64)
    ts = np.zeros(cap, np.int64)
    for s in range(n_blocks):
        _lookup_insert(tk, ts, block_keys[s], s)
    return tk, ts


@nb.njit(cache=True)
def _nonzero_voxels(block_keys, data, n_blocks):
    """Keys (unsorted) and rows of every voxel with a non-zero channel."""
    cnt = 0
    for s in range(n_blocks):
        for o in range(data.shape[1]):
            for c in range(data.shape[2]):
                if data[s, o, c] != 0:
                    cnt += 1
                    break
    keys = np.empty(cnt, np.int64)
    rows = np.empty((cnt, data.shape[2]), np.int64)
    off = 1 << 20
    m = (1 << 21) - 1
    n = 0
    for s in range(n_blocks):
        bk = block_keys[s]
        bi = ((bk >> 42) & m) - off
        bj = ((bk >> 21) & m) - off
        bz = (bk & m) - off
        for o in range(data.shape[1]):
            nz = False
            for c in range(data.shape[2]):
                if data[s, o, c] != 0:
                    nz = True
                    break
            if nz:
                i = bi * 8 + (o >> 6) + off
                j = bj * 8 + ((o >> 3) & 7) + off
                z = bz * 8 + (o & 7) + off
                keys[n] = (i << 42) | (j << 21) | z
                for c in range(data.shape[2]):
                    rows[n, c] = data[s, o, c]
                n += 1
    return keys, rows


class VoxelMemory:
    """Sparse hashed-block memory of integer channels (see the module docstring).

    Parameters
    ----------
    voxel_size : float, metres
    channels : sequence of :class:`ChannelSpec`
    """

    def __init__(self, voxel_size: float, channels: Sequence[ChannelSpec] = GEOMETRY_CHANNELS):
        self.voxel_size = float(voxel_size)
        self.specs = tuple(channels)
        names = [c.name for c in self.specs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate channel names {names}")
        self.offsets = {}
        o = 0
        for c in self.specs:
            self.offsets[c.name] = o
            o += c.width
        self.total_width = o
        # initial block storage: INITIAL_BYTES of zeros (untouched pages cost no memory), so that a
        # room-sized map never pays for growing (copying) its storage; a power of two, >= 256 blocks
        cap = 256
        while 2 * cap * BLOCK_VOXELS * self.total_width * 8 <= INITIAL_BYTES:
            cap *= 2
        self._table_keys = np.full(4 * cap, -1, np.int64)
        self._table_slots = np.zeros(4 * cap, np.int64)
        self._block_keys = np.zeros(cap, np.int64)
        self._data = np.zeros((cap, BLOCK_VOXELS, self.total_width), np.int64)
        self.n_blocks = 0
        self._nonzero = None  # (keys, rows) of the last nonzero(), until the next add

    def spec(self, name: str) -> ChannelSpec:
        for c in self.specs:
            if c.name == name:
                return c
        raise KeyError(name)

    def _cols(self, name: str, width: int) -> np.ndarray:
        if name not in self.offsets:
            raise ValueError(f"delta channel {name!r} is not a memory channel ({list(self.offsets)})")
        spec = self.spec(name)
        if width != spec.width:
            raise ValueError(f"delta channel {name!r} has width {width}, memory expects {spec.width}")
        return np.arange(self.offsets[name], self.offsets[name] + width, dtype=np.int64)

    def add(self, delta: "Delta | FrameDelta", sign: int = 1) -> None:
        """Add (``sign=+1``) or subtract (``sign=-1``) a delta (a :class:`FrameDelta`: each of its parts).
        Exact integer arithmetic."""
        if isinstance(delta, FrameDelta):
            for part in delta.parts:
                self.add(part, sign)
            return
        if len(delta) == 0 or not delta.channels:
            return
        self._nonzero = None
        vals, cols = self._values(delta)
        keys = np.ascontiguousarray(delta.keys)
        start = 0
        while True:
            start, self.n_blocks = _scatter_add(self._table_keys, self._table_slots, self._block_keys, self._data,
                                                self.n_blocks, keys, vals, cols, np.int64(sign), start)
            if start >= len(keys):
                break
            self._grow()

    def _values(self, delta: Delta) -> tuple[np.ndarray, np.ndarray]:
        """A delta's channels as one (n, m) int64 matrix and, per matrix column, its memory column.

        When every channel is a column slice of one 2-D array (a contributor's rows, e.g. the geometry
        delta's (n, 4) A N F O), that array is used as is; otherwise the channels are concatenated."""
        names = sorted(delta.channels)
        arrs = [delta.channels[n] for n in names]
        mcols = [self._cols(n, a.shape[1]) for n, a in zip(names, arrs)]
        base = arrs[0].base
        if isinstance(base, np.ndarray) and base.ndim == 2 and base.dtype == np.int64 and base.shape[0] == len(delta) \
                and base.strides[1] == base.itemsize:
            cols = np.full(base.shape[1], -1, np.int64)
            start = base.__array_interface__["data"][0]
            for a, mc in zip(arrs, mcols):
                off = a.__array_interface__["data"][0] - start
                c0, rem = divmod(off, base.itemsize)
                if (a.base is not base or rem or a.strides[0] != base.strides[0] or c0 + a.shape[1] > base.shape[1]
                        or (a.shape[1] > 1 and a.strides[1] != base.itemsize) or np.any(cols[c0:c0 + a.shape[1]] >= 0)):
                    break
                cols[c0:c0 + a.shape[1]] = mc
            else:
                return base, cols
        return np.ascontiguousarray(np.concatenate(arrs, axis=1)), np.concatenate(mcols)

    def _grow(self) -> None:
        if 2 * (self.n_blocks + 1) > self._table_keys.shape[0]:
            self._table_keys, self._table_slots = _rehash(self._block_keys, self.n_blocks,
                                                           2 * self._table_keys.shape[0])
        if self.n_blocks >= self._data.shape[0]:
            cap = 2 * self._data.shape[0]
            data = np.zeros((cap, BLOCK_VOXELS, self.total_width), np.int64)
            data[: self.n_blocks] = self._data[: self.n_blocks]
            self._data = data
            bk = np.zeros(cap, np.int64)
            bk[: self.n_blocks] = self._block_keys[: self.n_blocks]
            self._block_keys = bk

    def gather(self, keys: np.ndarray) -> dict:
        """Channel values at voxel ``keys`` (n,) int64 -> dict name -> (n, width) int64 (zeros if absent)."""
        keys = np.ascontiguousarray(keys, dtype=np.int64)
        out = np.zeros((len(keys), self.total_width), np.int64)
        _gather(self._table_keys, self._table_slots, self._data, keys, out)
        return self._split(out)

    def _split(self, rows: np.ndarray) -> dict:
        return {c.name: rows[:, self.offsets[c.name]: self.offsets[c.name] + c.width] for c in self.specs}

    def nonzero(self) -> tuple[np.ndarray, dict]:
        """Every voxel with a non-zero channel, in key order.

        Returns
        -------
        keys : (n,) int64 sorted
        channels : dict name -> (n, width) int64
        """
        if self._nonzero is None:  # a save and an export of the same memory scan it once
            keys, rows = _nonzero_voxels(self._block_keys, self._data, self.n_blocks)
            order = np.argsort(keys, kind="stable")
            keys, rows = keys[order], rows[order]
            keys.flags.writeable = rows.flags.writeable = False
            self._nonzero = (keys, rows)
        keys, rows = self._nonzero
        return keys, self._split(rows)

    def to_arrays(self) -> dict:
        """The canonical on-disk form (see docs/mapping.md): equal sums give equal arrays."""
        keys, ch = self.nonzero()
        out = {"keys": keys, "voxel_size": np.float64(self.voxel_size),
               "channel_names": np.array([c.name for c in self.specs], dtype=np.str_),
               "channel_widths": np.array([c.width for c in self.specs], dtype=np.int64),
               "channel_kinds": np.array([c.kind for c in self.specs], dtype=np.str_),
               "fixed_scale": np.int64(FIXED_SCALE)}
        for name, arr in ch.items():
            out[f"ch_{name}"] = arr
        return out

    @classmethod
    def from_arrays(cls, z: Mapping[str, np.ndarray], where=None) -> "VoxelMemory":
        """Rebuild a memory from :meth:`to_arrays` output (e.g. an opened ``memory.npz``)."""
        try:
            specs = [ChannelSpec(str(n), int(w), str(k)) for n, w, k in
                     zip(z["channel_names"], z["channel_widths"], z["channel_kinds"])]
            if int(z["fixed_scale"]) != FIXED_SCALE:
                raise PanovoccError(f"fixed_scale {int(z['fixed_scale'])} != {FIXED_SCALE}", where)
            mem = cls(float(z["voxel_size"]), specs)
            keys = np.asarray(z["keys"], np.int64)
            mem.add(Delta(keys, {s.name: z[f"ch_{s.name}"] for s in specs}))
        except KeyError as e:
            raise PanovoccError(f"memory file lacks {e}", where) from None
        return mem

    def __len__(self) -> int:
        return len(self.nonzero()[0])
