"""The persistent voxel memory: additive integer channels in spatially hashed 8^3 blocks.

A frame's contribution is a sparse :class:`Delta`: sorted unique int64 voxel keys
(:func:`panovocc_cli.geometry.lattice.pack_keys`) and named integer channel arrays. The memory is
the sum of the retained deltas. Integer addition is exact and order-independent, so subtracting a
delta and adding it back leaves the memory bit-identical (the reversible persistent update, RPU).

Channels are generic: each has a name, a width (columns) and a kind. ``"fixed"`` channels hold float
quantities as ``round(value * FIXED_SCALE)`` int64 (fixed point, 2^-16 resolution); ``"int"`` channels
hold exact counts. Geometry uses A (fixed), N, F, O (int); the semantic stage adds its own channels
(E, S, rgb_sum, normal_sum, count) through the same mechanism.

Storage (docs/mapping.md, "Memory layout"): a block key (the voxel index divided by 8, packed like a
voxel key) maps to a block slot through an open-addressing hash table compiled with numba.

* The geometry channels (A N F O, the *dense* group) are kept for every voxel of an allocated block, in
  the smallest type their values need: int32 (16 bytes a voxel), widened to int64 for the whole group
  the first time a sum would leave int32 (a value is never wrapped: past int64 an add is refused).
* Every other channel (the semantic ones, the *sparse* group) is kept only for voxels where such
  evidence fell: a block that has some points to a page of 512 row numbers, and a voxel with evidence
  owns one row of the sparse group (int32, widened to int64 like the geometry). Free-space voxels pay
  nothing for the vocabulary.
* Growth without a copy: block, page and row storage is reserved as untouched zero pages (Linux:
  anonymous mappings with MAP_NORESERVE) large enough for a building; pages cost memory once written.
  Past the reservation (or where it cannot be made) the storage doubles by copying.

Saved memories list only the non-zero voxels in key order, so two memories with equal sums have equal
bytes whatever their history or storage types.
"""

from __future__ import annotations

import mmap
import sys
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numba as nb
import numpy as np

from ..errors import PanovoccError
from ..geometry.lattice import pack_index, unpack_index

FIXED_SCALE = 2 ** 16  # fixed-point scale of "fixed" channels: value = stored / FIXED_SCALE
BLOCK = 8  # voxels per block edge
BLOCK_VOXELS = BLOCK ** 3
GEOMETRY_NAMES = ("A", "N", "F", "O")  # the dense group: kept for every voxel of a block
RESERVE_BLOCKS = 1 << 20  # blocks (512 M voxels) reserved up front where untouched pages cost nothing
RESERVE_ROWS = 1 << 26  # sparse-group rows reserved likewise
FALLBACK_BLOCKS = 1 << 10  # initial blocks where nothing can be reserved (then doubled by copying)
LOAD_CHUNK = 1 << 18  # rows a memory file is added in at a time (from_arrays): a few MB of (rows, channels)
#                       int64, reused from the heap, instead of one matrix of every voxel (0.5 GB for a building)
SKIP_UNCHANGED = True  # VoxelMemory.replace leaves out the kept voxels its difference does not change (False:
#                        every voxel of the union is added, as before; scripts/revise_ab.py swap compares the two)
_MAP_NORESERVE = 0x4000  # Linux mmap flag: no swap reservation for the mapping (mmap lacks the name)
_I32 = (int(np.iinfo(np.int32).min), int(np.iinfo(np.int32).max))
_I64 = (int(np.iinfo(np.int64).min), int(np.iinfo(np.int64).max))
_pack = nb.njit(inline="always")(pack_index)  # the lattice's key layout, compiled into the kernels below
_unpack = nb.njit(inline="always")(unpack_index)


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
OFFSET_CHANNEL = ChannelSpec("P", 10, "int")  # surface offsets: frames with a measurement in the voxel, their
# summed mean offset from its centre (3), mean normal towards the camera (3) and squared mean offset (3)
# (psvf.update._offset_rows); a sparse-group channel: kept only for voxels that held a measurement


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
    channels : dict name -> (n, width) int64 or int32 (only channels the contributor produces)
    factors : dict name -> (factor channel, denominator): how a channel factors (``channel = factor * m /
        denominator`` with m an integer array), which the delta log stores instead of the product; a
        hint only (the writer checks it and stores the product where it does not hold)
    """

    keys: np.ndarray
    channels: dict
    factors: dict = field(default_factory=dict)

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
    """A channel as (n, width) int64, or int32 as it is (an (n,) array is one column; an empty delta keeps
    its width). int32 is kept: the geometry kernel's A N F O rows (:func:`~.psvf.update._delta_rows`) are
    int32 when they fit, and every pass over a delta reads either type (sums in int64)."""
    a = np.asarray(values)
    if a.dtype != np.int32:
        a = a.astype(np.int64, copy=False)
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
    mostly zeros to allocate, add, scan and compress.
    """

    parts: tuple
    observation: object = None  # what the frame's semantic part was computed from besides depth, colours and
    #                             pose (a SemanticObservation), kept so that a revision needs no segmenter

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


# ---------------------------------------------------------------------------------------------
# storage


def _reserve(n: int, tail: tuple, dtype) -> np.ndarray:
    """Zeros of shape ``(n, *tail)``: on Linux an anonymous MAP_NORESERVE mapping, whose pages cost memory
    only once written; elsewhere (or if the mapping is refused) ordinary zeros."""
    dtype = np.dtype(dtype)
    nbytes = int(n) * int(np.prod(tail, dtype=np.int64)) * dtype.itemsize
    if nbytes > 0 and sys.platform.startswith("linux"):
        try:
            mm = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | _MAP_NORESERVE,
                           prot=mmap.PROT_READ | mmap.PROT_WRITE)
            return np.frombuffer(mm, dtype).reshape((int(n),) + tuple(tail))
        except (OSError, ValueError, OverflowError):
            pass
    return np.zeros((int(n),) + tuple(tail), dtype)


def _grown(a: np.ndarray, used: int, cap: int, dtype=None) -> np.ndarray:
    """A copy of ``a[:used]`` in new storage of ``cap`` rows (and type ``dtype``, default ``a``'s)."""
    out = _reserve(cap, a.shape[1:], a.dtype if dtype is None else dtype)
    out[:used] = a[:used]
    return out


# ---------------------------------------------------------------------------------------------
# numba kernels: block hash table, scatter-add, gathers


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
    """Return (slot, inserted)."""
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


@nb.njit(cache=True, inline="always")
def _block_key_and_offset(key):
    """A voxel key -> (its block's key, packed like a voxel key from index // 8; the voxel's offset in it)."""
    i, j, k = _unpack(key)
    return _pack(i >> 3, j >> 3, k >> 3), ((i & 7) << 6) | ((j & 7) << 3) | (k & 7)


@nb.njit(cache=True, inline="always")
def _voxel_key(bkey, o):
    """Inverse of :func:`_block_key_and_offset`."""
    bi, bj, bk = _unpack(bkey)
    return _pack(bi * 8 + (o >> 6), bj * 8 + ((o >> 3) & 7), bk * 8 + (o & 7))


@nb.njit(cache=True, inline="always")
def _cache_entry(bkey):
    """A block's entry in the kernels' 64-entry direct-mapped slot cache: the low 3 bits of its k and j."""
    _, bj, bk = _unpack(bkey)
    return (bk & 7) | ((bj & 7) << 3)


@nb.njit(cache=True)
def _slot(table_keys, table_slots, block_keys, n_blocks, cache_keys, cache_slots, bkey):
    """(slot of block ``bkey``, allocating it; n_blocks), remembered in the slot cache. Slot -1: the table or
    the block storage is full. Called on a miss of the cache only.

    Block slots are remembered in a small direct-mapped cache indexed by the block's low (j, k) bits
    (:func:`_cache_entry`): keys in lattice order revisit the same few dozen blocks row after row, so the hash
    table is probed about once per block and frame. The kernels read the cache themselves and call this on
    a miss only: called at every row (even inlined, as it was), the call with its seven arrays was 90 % of
    an add (``_add_dense``: 10.7 against 1.4 ms for the 188,440 rows of a frame of the seed-0 home at
    1024x512; the same rows, slots and sums; docs/mapping.md, "Speed")."""
    e = _cache_entry(bkey)
    if n_blocks >= block_keys.shape[0] or 2 * (n_blocks + 1) > table_keys.shape[0]:
        slot = _find(table_keys, table_slots, bkey)  # might need a new block: look, do not insert
        if slot < 0:
            return -1, n_blocks
    else:
        slot, ins = _lookup_insert(table_keys, table_slots, bkey, n_blocks)
        if ins:
            block_keys[n_blocks] = bkey
            n_blocks += 1
    cache_keys[e] = bkey
    cache_slots[e] = slot
    return slot, n_blocks


@nb.njit(cache=True, nogil=True)  # releases the GIL: Mapper.revise_many swaps on a second thread
def _add_dense(table_keys, table_slots, block_keys, n_blocks, geo, keys, vals, cols, sign, start, lo, hi):
    """Add ``sign * vals[:, c]`` into column ``cols[c]`` (< 0: skipped) of the dense storage at ``keys``.

    Returns (status, index reached, n_blocks): status 0 done, 1 the table or block storage is full (grow
    and call again from the index), 2 the row at the index would leave [lo, hi] (widen; nothing of that
    row was added)."""
    nc = cols.shape[0]
    cache_keys = np.full(64, -1, np.int64)
    cache_slots = np.zeros(64, np.int64)
    for n in range(start, keys.shape[0]):
        bkey, o = _block_key_and_offset(keys[n])
        e = _cache_entry(bkey)
        if cache_keys[e] == bkey:  # the cache read here: no call at every row (see _slot)
            slot = cache_slots[e]
        else:
            slot, n_blocks = _slot(table_keys, table_slots, block_keys, n_blocks, cache_keys, cache_slots, bkey)
        if slot < 0:
            return 1, n, n_blocks
        for c in range(nc):
            if cols[c] >= 0:
                d = sign * vals[n, c]
                old = np.int64(geo[slot, o, cols[c]])
                if (d > 0 and old > hi - d) or (d < 0 and old < lo - d):
                    return 2, n, n_blocks
        for c in range(nc):
            if cols[c] >= 0:
                geo[slot, o, cols[c]] += sign * vals[n, c]
    return 0, keys.shape[0], n_blocks


@nb.njit(cache=True, nogil=True)  # releases the GIL: Mapper.revise_many swaps on a second thread
def _add_sparse(table_keys, table_slots, block_keys, n_blocks, page_of, pages, n_pages, rows, n_rows,
                keys, vals, cols, sign, start, lo, hi):
    """Like :func:`_add_dense` for the sparse group: a voxel gets a row (and its block a page of row
    numbers) the first time a non-zero value reaches it. Returns (status, index, n_blocks, n_pages,
    n_rows); status 1 also when the page or row storage is full."""
    nc = cols.shape[0]
    cache_keys = np.full(64, -1, np.int64)
    cache_slots = np.zeros(64, np.int64)
    for n in range(start, keys.shape[0]):
        nz = False
        for c in range(nc):
            if cols[c] >= 0 and vals[n, c] != 0:
                nz = True
                break
        if not nz:
            continue
        bkey, o = _block_key_and_offset(keys[n])
        e = _cache_entry(bkey)
        if cache_keys[e] == bkey:  # the cache read here: no call at every row (see _slot)
            slot = cache_slots[e]
        else:
            slot, n_blocks = _slot(table_keys, table_slots, block_keys, n_blocks, cache_keys, cache_slots, bkey)
        if slot < 0:
            return 1, n, n_blocks, n_pages, n_rows
        p = page_of[slot]
        if p == 0:
            if n_pages >= pages.shape[0]:
                return 1, n, n_blocks, n_pages, n_rows
            n_pages += 1
            page_of[slot] = n_pages
            p = n_pages
        r = pages[p - 1, o]
        if r == 0:
            if n_rows >= rows.shape[0]:
                return 1, n, n_blocks, n_pages, n_rows
            n_rows += 1
            pages[p - 1, o] = n_rows
            r = n_rows
        for c in range(nc):
            if cols[c] >= 0:
                d = sign * vals[n, c]
                old = np.int64(rows[r - 1, cols[c]])
                if (d > 0 and old > hi - d) or (d < 0 and old < lo - d):
                    return 2, n, n_blocks, n_pages, n_rows
        for c in range(nc):
            if cols[c] >= 0:
                rows[r - 1, cols[c]] += sign * vals[n, c]
    return 0, keys.shape[0], n_blocks, n_pages, n_rows


def _column_matrix(arrs, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Channels ((n, w) arrays, in order) as (matrix, src): their concatenation along the columns is
    ``matrix[:, src]``. When every channel is a column view of one (n, k) int64 or int32 array (a contributor's
    rows, e.g. the geometry delta's (n, 4) A N F O), that array as it is (no copy); otherwise the
    concatenation (int64 when the types differ)."""
    base = arrs[0].base
    if isinstance(base, np.ndarray) and base.ndim == 2 and base.dtype in (np.int32, np.int64) and base.shape[0] == n \
            and base.strides[1] == base.itemsize:
        src = []
        start = base.__array_interface__["data"][0]
        for a in arrs:
            c0, rem = divmod(a.__array_interface__["data"][0] - start, base.itemsize)
            if (a.base is not base or a.dtype != base.dtype or rem or c0 < 0 or a.strides[0] != base.strides[0]
                    or c0 + a.shape[1] > base.shape[1] or (a.shape[1] > 1 and a.strides[1] != base.itemsize)):
                break
            src.extend(range(c0, c0 + a.shape[1]))
        else:
            return base, np.array(src, np.int64)
    matrix = np.ascontiguousarray(np.concatenate(arrs, axis=1))
    return matrix, np.arange(matrix.shape[1], dtype=np.int64)


@nb.njit(cache=True, nogil=True)  # releases the GIL: Mapper.revise_many swaps on a second thread
def _difference(ka, va, ca, kb, vb, cb, skip_kept):
    """``vb[:, cb] - va[:, ca]`` over the union of sorted unique keys ``ka`` (na,) and ``kb`` (nb,) (values
    (n, m) int64, the m columns ``ca``/``cb`` of each side's matrix, :func:`_column_matrix`; a row absent from
    one side counting as zeros): (ok, keys (n,), values (n, m)); ok False when a difference
    would pass int64 (nothing is wrapped: the caller then subtracts and adds apart). ``skip_kept``: rows of
    keys in ``ka`` whose difference is zero are left out (adding them changes nothing: their blocks are
    allocated, since ``va`` was added before; a pose correction leaves about three quarters of a frame's
    union unchanged); keys only in ``kb`` are kept even when zero (adding them allocates their block)."""
    na, nb_, m = ka.shape[0], kb.shape[0], ca.shape[0]
    i = j = n = 0
    while i < na and j < nb_:
        a, b = ka[i], kb[j]
        i += a <= b
        j += b <= a
        n += 1
    n += na - i + nb_ - j
    keys = np.empty(n, np.int64)
    vals = np.empty((n, m), np.int64)
    lo, hi = np.iinfo(np.int64).min, np.iinfo(np.int64).max
    i = j = 0
    r = 0
    for _ in range(n):
        take_a = j >= nb_ or (i < na and ka[i] <= kb[j])
        take_b = i >= na or (j < nb_ and kb[j] <= ka[i])
        zero = True
        for c in range(m):
            a = va[i, ca[c]] if take_a else 0
            b = vb[j, cb[c]] if take_b else 0
            if (a < 0 and b > hi + a) or (a > 0 and b < lo + a):
                return False, keys[:0], vals[:0]
            vals[r, c] = b - a
            zero = zero and a == b
        keys[r] = ka[i] if take_a else kb[j]
        if not (skip_kept and take_a and zero):
            r += 1
        i += take_a
        j += take_b
    return True, keys[:r], vals[:r]


@nb.njit(cache=True, nogil=True)  # runs on the swap thread of Mapper.revise_many
def _mark_blocks(table_keys, table_slots, keys, marks):
    """marks[slot] = 1 for the block of each voxel key in ``keys`` (blocks not allocated are skipped)."""
    cache_keys = np.full(64, -1, np.int64)
    cache_slots = np.zeros(64, np.int64)
    for n in range(keys.shape[0]):
        bkey, _ = _block_key_and_offset(keys[n])
        e = _cache_entry(bkey)
        if cache_keys[e] != bkey:
            cache_keys[e] = bkey
            cache_slots[e] = _find(table_keys, table_slots, bkey)
        if cache_slots[e] >= 0:
            marks[cache_slots[e]] = 1


@nb.njit(cache=True)
def _rehash(block_keys, n_blocks, cap):
    tk = np.full(cap, -1, np.int64)
    ts = np.zeros(cap, np.int64)
    for s in range(n_blocks):
        _lookup_insert(tk, ts, block_keys[s], s)
    return tk, ts


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _locate(table_keys, table_slots, keys, loc):
    """loc[n] = slot * 512 + offset of voxel keys[n], -1 when its block is not allocated."""
    cache_keys = np.full(64, -1, np.int64)
    cache_slots = np.zeros(64, np.int64)
    for n in range(keys.shape[0]):
        bkey, o = _block_key_and_offset(keys[n])
        e = _cache_entry(bkey)
        if cache_keys[e] != bkey:  # the table probed on a miss only (a call at every row is slow: see _slot)
            cache_keys[e] = bkey
            cache_slots[e] = _find(table_keys, table_slots, bkey)
        s = cache_slots[e]
        loc[n] = -1 if s < 0 else s * 512 + o


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _dense_at(geo, loc, out):
    """out[n] = dense row at loc[n] (zeros where loc < 0), int64."""
    for n in range(loc.shape[0]):
        if loc[n] >= 0:
            s = loc[n] >> 9
            o = loc[n] & 511
            for c in range(geo.shape[2]):
                out[n, c] = geo[s, o, c]


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _sparse_at(page_of, pages, rows, loc, out):
    """out[n] = sparse row at loc[n] (zeros where the voxel has none), int64."""
    for n in range(loc.shape[0]):
        if loc[n] >= 0:
            p = page_of[loc[n] >> 9]
            if p > 0:
                r = pages[p - 1, loc[n] & 511]
                if r > 0:
                    for c in range(rows.shape[1]):
                        out[n, c] = rows[r - 1, c]


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _ordered_nonzero(slots, bx, by, geo, page_of, pages, rows, has_sparse, b0, b1, dx0, dx1, loc):
    """The voxels with a non-zero channel, in key order, of the blocks ``slots[b0:b1]`` (sorted by block key,
    whole x-slabs of blocks: block coordinates ``bx`` equal within one), at x offsets ``dx0 <= dx < dx1``
    in their block: their locations (slot * 512 + offset) into ``loc``; returns their count (:func:`_keys_at`
    gives their keys). Keys sort x-major, then y, then z, so a slab's voxels come x offset by x offset,
    each as its rows of blocks (equal ``by``) y offset by y offset, block after block (ascending z)."""
    cnt = 0
    a = b0
    while a < b1:
        e = a
        while e < b1 and bx[e] == bx[a]:
            e += 1
        for dx in range(dx0, dx1):
            j = a
            while j < e:
                k = j
                while k < e and by[k] == by[j]:
                    k += 1
                for dy in range(8):
                    for m in range(j, k):
                        s = slots[m]
                        p = page_of[s] if has_sparse else 0
                        for dz in range(8):
                            o = (dx << 6) | (dy << 3) | dz
                            nz = False  # a non-zero channel (written out: a call at every voxel is slow, see _slot)
                            for c in range(geo.shape[2]):
                                if geo[s, o, c] != 0:
                                    nz = True
                                    break
                            if not nz and p > 0:
                                r = pages[p - 1, o]
                                if r > 0:
                                    for c in range(rows.shape[1]):
                                        if rows[r - 1, c] != 0:
                                            nz = True
                                            break
                            if nz:
                                loc[cnt] = s * 512 + o
                                cnt += 1
                j = k
        a = e
    return cnt


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _keys_at(block_keys, loc, out):
    """out[n] = the key of the voxel at location loc[n] (slot * 512 + offset)."""
    for n in range(loc.shape[0]):
        out[n] = _voxel_key(block_keys[loc[n] >> 9], loc[n] & 511)


@nb.njit(cache=True, nogil=True)  # read while the memory is saved on another thread (revise)
def _has_row(page_of, pages, loc, out):
    """out[n] = whether the voxel at loc[n] owns a sparse-group row."""
    for n in range(loc.shape[0]):
        p = page_of[loc[n] >> 9]
        out[n] = p > 0 and pages[p - 1, loc[n] & 511] > 0


class NonzeroChannels(Mapping):
    """The channels of a memory's non-zero voxels, read from the memory when asked for (name -> (n, width)
    int64, in key order): an export that needs the semantic channels only at its occupied voxels reads
    them there (:meth:`at`) instead of copying them for every voxel."""

    def __init__(self, memory: "VoxelMemory", loc: np.ndarray):
        self._memory, self._loc, self._cache = memory, loc, {}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cache:  # a group's channels are read together (one array, sliced)
            dense = name in GEOMETRY_NAMES
            group = [s.name for s in self._memory.specs if (s.name in GEOMETRY_NAMES) == dense]
            self._cache.update(self._memory._channels_at(self._loc, group))
        return self._cache[name]

    def __iter__(self):
        return iter(s.name for s in self._memory.specs)

    def __contains__(self, name) -> bool:  # without reading the channel (Mapping's default would read it)
        return any(s.name == name for s in self._memory.specs)

    def __len__(self) -> int:
        return len(self._memory.specs)

    def at(self, pos: np.ndarray, names=None) -> dict:
        """Channels (all, or ``names``) at positions ``pos`` (m,) of the key order."""
        names = list(self) if names is None else list(names)
        return self._memory._channels_at(self._loc[np.asarray(pos, np.int64)], names)


SAVE_CHUNK = 1 << 18  # allocated voxels a streamed save (MemoryChunks) reads at a time


class MemoryChunks:
    """A memory's canonical arrays (:meth:`VoxelMemory.to_arrays` with ``sparse=True``) read a key range at
    a time, for a ``memory.npz`` written as a stream (:func:`panovocc_cli.io.mapstore.write_memory`): no
    array of every non-zero voxel is made. A chunk is whole x-slabs of blocks (their voxels in key order
    without a sort: :func:`_ordered_nonzero`) of about ``chunk`` allocated voxels; a slab larger than that
    is read a few x offsets at a time. The memory must not change while it is read.

    Attributes: ``header`` (the small arrays of ``to_arrays``: voxel size, channel names, widths, kinds,
    fixed scale), ``n`` (non-zero voxels), ``names`` (channel names in order).
    """

    def __init__(self, memory: "VoxelMemory", chunk: int | None = None):
        chunk = SAVE_CHUNK if chunk is None else int(chunk)
        self._memory = memory
        self.header = memory._header()
        self.names = tuple(s.name for s in memory.specs)
        if memory._nonzero is not None:  # the key order a scan made already (an export's): its slices
            loc = memory._nonzero[1]
            self._plan = [(a, loc[a:a + chunk]) for a in range(0, len(loc), chunk)]
            self.n = len(loc)
            return
        bkeys = memory._block_keys[:memory.n_blocks]
        self._slots = np.argsort(bkeys, kind="stable").astype(np.int64)
        bx, by, _ = unpack_index(bkeys[self._slots])
        self._bx, self._by = np.ascontiguousarray(bx, np.int64), np.ascontiguousarray(by, np.int64)
        cuts = np.flatnonzero(bx[1:] != bx[:-1]) + 1
        per = max(chunk // BLOCK_VOXELS, 1)  # blocks a chunk of whole slabs holds at most
        plan, group = [], None
        for a, e in zip(np.r_[0, cuts].astype(int), np.r_[cuts, len(bx)].astype(int)):
            if len(bx) == 0:
                break
            if group is not None and (e - a > per or e - group[0] > per):
                plan.append((group[0], group[1], 0, BLOCK))
                group = None
            if e - a > per:  # one slab over the chunk: a few x offsets of it at a time
                step = int(min(max(chunk // ((e - a) * BLOCK * BLOCK), 1), BLOCK))
                plan += [(a, e, dx, min(dx + step, BLOCK)) for dx in range(0, BLOCK, step)]
            else:
                group = (a if group is None else group[0], e)
        if group is not None:
            plan.append((group[0], group[1], 0, BLOCK))
        # one scan: each chunk's voxel locations, kept in 4 bytes a voxel (the passes of a save read them
        # again and again: a scan of every allocated voxel each time cost more than the encoding)
        ltype = np.int32 if memory.n_blocks * BLOCK_VOXELS < 2 ** 31 else np.int64
        self._plan, start = [], 0
        for b0, b1, dx0, dx1 in plan:
            loc = np.empty((b1 - b0) * BLOCK * BLOCK * (dx1 - dx0), np.int64)
            m = memory
            cnt = _ordered_nonzero(self._slots, self._bx, self._by, m._geo, m._page_of, m._pages, m._rows,
                                   bool(m.sparse_width), b0, b1, dx0, dx1, loc)
            self._plan.append((start, loc[:cnt].astype(ltype)))
            start += cnt
        self.n = start

    def chunks(self, names=(), keys: bool = True):
        """Yield ``(start, keys, channels)`` chunk by chunk in key order: ``keys`` (m,) int64 the voxels
        ``start .. start + m - 1`` of the key order (``keys=False``: an empty array of length m, the keys
        not computed); ``channels`` name -> (m, width) in the stored type
        (the geometry) or a :class:`~panovocc_cli.io.mapstore.SparseRows` over the whole order (the sparse
        group: the voxels that own a row), for ``names`` only."""
        from ..io.mapstore import SparseRows

        m = self._memory
        dense = [s for s in names if s in GEOMETRY_NAMES]
        rest = [s for s in names if s not in GEOMETRY_NAMES]
        for start, loc in self._plan:
            loc, cnt = loc.astype(np.int64), len(loc)
            out_keys = np.empty(cnt, np.int64) if keys else np.broadcast_to(np.int64(0), (cnt,))
            if keys:
                _keys_at(m._block_keys, loc, out_keys)
            out = m._channels_at(loc, dense, stored=True) if dense else {}
            if rest:
                has = np.zeros(cnt, np.bool_)
                _has_row(m._page_of, m._pages, loc, has)
                pos = np.flatnonzero(has)
                at = m._channels_at(loc[pos], rest, stored=True)
                out.update({k: SparseRows(start + pos, at[k], self.n) for k in rest})
            yield start, out_keys, out


def _same_rows(channels: Mapping) -> list:
    """Names of channels stored as rows (``io.mapstore.SparseRows``), grouped by equal row positions (a
    memory file's semantic channels mostly share theirs), each group in the order given."""
    groups: list = []
    for name, v in channels.items():
        for g in groups:
            r = channels[g[0]].rows
            if len(r) == len(v.rows) and np.array_equal(r, v.rows):
                g.append(name)
                break
        else:
            groups.append([name])
    return groups


class VoxelMemory:
    """Sparse hashed-block memory of integer channels (see the module docstring).

    Parameters
    ----------
    voxel_size : float, metres
    channels : sequence of :class:`ChannelSpec`; those named A, N, F, O form the dense group, the others
        the sparse group
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
        # every logical column (offsets order) -> its column in the dense or the sparse storage (-1: other group)
        self._dense_col = np.full(o, -1, np.int64)
        self._sparse_col = np.full(o, -1, np.int64)
        nd = ns = 0
        for c in self.specs:
            cols = np.arange(self.offsets[c.name], self.offsets[c.name] + c.width)
            if c.name in GEOMETRY_NAMES:
                self._dense_col[cols] = np.arange(nd, nd + c.width)
                nd += c.width
            else:
                self._sparse_col[cols] = np.arange(ns, ns + c.width)
                ns += c.width
        self.dense_width, self.sparse_width = nd, ns
        reserve = sys.platform.startswith("linux")
        cap = RESERVE_BLOCKS if reserve else FALLBACK_BLOCKS
        self._table_keys = np.full(4096, -1, np.int64)
        self._table_slots = np.zeros(4096, np.int64)
        self._block_keys = _reserve(cap, (), np.int64)
        self._geo = _reserve(cap, (BLOCK_VOXELS, nd), np.int32)
        self.n_blocks = 0
        self._page_of = _reserve(cap if ns else 1, (), np.int32)
        self._pages = _reserve(cap if ns else 1, (BLOCK_VOXELS,), np.int32)
        self._rows = _reserve((RESERVE_ROWS if reserve else BLOCK_VOXELS * FALLBACK_BLOCKS) if ns else 1, (max(ns, 1),),
                              np.int32)
        self.n_pages = self.n_rows = 0
        self._nonzero = None  # (keys, locations) of the last nonzero(), until the next add
        self._marks = None  # with track_changes(): 1 per block slot that an add has reached since

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

    # -- sizes -----------------------------------------------------------------------------------
    def nbytes(self) -> dict:
        """Bytes the memory holds in RAM by part: ``dense`` (allocated blocks' geometry), ``pages`` and
        ``rows`` (the sparse group), ``table`` (hash table and block keys)."""
        return {"dense": self.n_blocks * BLOCK_VOXELS * self.dense_width * self._geo.itemsize,
                "pages": self.n_pages * BLOCK_VOXELS * 4 + (self.n_blocks * 4 if self.sparse_width else 0),
                "rows": self.n_rows * self.sparse_width * self._rows.itemsize,
                "table": self._table_keys.nbytes + self._table_slots.nbytes + self.n_blocks * 8}

    @property
    def allocated_voxels(self) -> int:
        """Voxels of the allocated blocks (512 a block)."""
        return self.n_blocks * BLOCK_VOXELS

    # -- changes ---------------------------------------------------------------------------------
    def add(self, delta: "Delta | FrameDelta", sign: int = 1) -> None:
        """Add (``sign=+1``) or subtract (``sign=-1``) a delta (a :class:`FrameDelta`: each of its parts).
        Exact integer arithmetic; a sum past int64 is refused (:class:`PanovoccError`), never wrapped."""
        if isinstance(delta, FrameDelta):
            done = []
            try:
                for part in delta.parts:
                    self.add(part, sign)
                    done.append(part)
            except PanovoccError:  # a refused part: take the parts added before it out again
                for part in done:
                    self.add(part, -sign)
                raise
            return
        if len(delta) == 0 or not delta.channels:
            return
        self._nonzero = None
        vals, cols = self._values(delta)
        keys = np.ascontiguousarray(delta.keys)
        valid = cols >= 0
        dcols = np.where(valid, self._dense_col[np.maximum(cols, 0)], -1)
        scols = np.where(valid, self._sparse_col[np.maximum(cols, 0)], -1)
        has_dense, has_sparse = bool(np.any(dcols >= 0)), bool(np.any(scols >= 0))
        if has_dense:
            stop = self._add_group("dense", keys, vals, dcols, sign)
            if stop is not None:  # refused at row ``stop``: the rows before it are taken out again
                self._add_group("dense", keys[:stop], vals[:stop], dcols, -sign)
                self._refuse("dense", keys[stop])
        if has_sparse:
            stop = self._add_group("sparse", keys, vals, scols, sign)
            if stop is not None:
                self._add_group("sparse", keys[:stop], vals[:stop], scols, -sign)
                if has_dense:
                    self._add_group("dense", keys, vals, dcols, -sign)
                self._refuse("sparse", keys[stop])
        if self._marks is not None:
            if len(self._marks) < self.n_blocks:
                self._marks = np.concatenate([self._marks, np.zeros(len(self._block_keys) - len(self._marks), np.uint8)])
            _mark_blocks(self._table_keys, self._table_slots, keys, self._marks)

    def replace(self, old: "Delta | FrameDelta", new: "Delta | FrameDelta") -> None:
        """Subtract ``old`` and add ``new`` (a revised frame's kept and recomputed deltas): the memory that
        ``add(old, -1)`` then ``add(new, +1)`` gives, bit for bit, with the same blocks and rows allocated,
        in one pass over the union of their keys for each part (a frame moved by a pose correction keeps
        most of its voxels, so the union is about one delta, not two), less the voxels of ``old`` whose
        values the difference leaves as they are (three quarters of the union on the building; a block
        that only such voxels of ``old`` would allocate is not: one of a loaded memory, which allocates the
        blocks of its non-zero voxels, whose voxels of ``old`` are all zero). Parts of ``new`` whose channels no
        part of ``old`` has, or a difference past int64, take the two passes. A refused sum leaves the
        memory as it was (:class:`PanovoccError`)."""
        olds = list(old.parts) if isinstance(old, FrameDelta) else [old]
        news = list(new.parts) if isinstance(new, FrameDelta) else [new]
        olds = [p for p in olds if len(p) and p.channels]
        news = [p for p in news if len(p) and p.channels]
        diffs = []
        for n in news:
            names = sorted(n.channels)
            o = next((o for o in olds if sorted(o.channels) == names
                      and all(o.channels[k].shape[1] == n.channels[k].shape[1] for k in names)), None)
            if o is None:
                break
            # each side's channels as one matrix and the columns to read: a contributor's rows as they are (the
            # geometry kernel's (n, 4) A N F O), without a concatenated copy (~4 ms a building frame)
            va, ca = _column_matrix([o.channels[k] for k in names], len(o))
            vb, cb = _column_matrix([n.channels[k] for k in names], len(n))
            ok, keys, vals = _difference(o.keys, va, ca, n.keys, vb, cb, SKIP_UNCHANGED)
            if not ok:
                break
            widths = np.cumsum([0] + [n.channels[k].shape[1] for k in names])
            diffs.append(Delta(keys, {k: vals[:, widths[c]:widths[c + 1]] for c, k in enumerate(names)}))
        if len(diffs) == len(news) == len(olds):
            self.add(FrameDelta(tuple(diffs)))
            return
        self.add(FrameDelta(tuple(olds)), -1)
        try:
            self.add(FrameDelta(tuple(news)), +1)
        except PanovoccError:
            self.add(FrameDelta(tuple(olds)), +1)
            raise

    def track_changes(self) -> None:
        """From now on, remember which blocks an add (or :meth:`replace`) reaches: :meth:`changed_blocks`."""
        self._marks = np.zeros(len(self._block_keys), np.uint8)

    def changed_blocks(self) -> np.ndarray:
        """Block indices (m, 3) int64 (a block is :data:`BLOCK` voxels a side; voxel index // BLOCK), sorted by
        key: the blocks an add reached since :meth:`track_changes`. Every voxel whose channels changed lies
        in one (:func:`.export.export_memory`'s incremental labels, ``panovocc revise``). Costs one byte a
        block slot while tracked, instead of every changed voxel's key."""
        if self._marks is None:
            raise PanovoccError("changed_blocks needs track_changes() first")
        slots = np.flatnonzero(self._marks[:self.n_blocks])
        return np.stack(unpack_index(np.sort(self._block_keys[slots])), axis=1).astype(np.int64).reshape(-1, 3)

    def _add_group(self, group: str, keys, vals, cols, sign) -> int | None:
        """Scatter-add one group's columns; growing and widening as needed. Returns None when done, or the
        row at which a sum would pass int64 (the rows before it were added)."""
        sign = np.int64(sign)
        start = 0
        while True:
            if group == "dense":
                lo, hi = _I32 if self._geo.dtype == np.int32 else _I64
                status, start, self.n_blocks = _add_dense(self._table_keys, self._table_slots, self._block_keys,
                                                          self.n_blocks, self._geo, keys, vals, cols, sign, start,
                                                          lo, hi)
            else:
                lo, hi = _I32 if self._rows.dtype == np.int32 else _I64
                status, start, self.n_blocks, self.n_pages, self.n_rows = _add_sparse(
                    self._table_keys, self._table_slots, self._block_keys, self.n_blocks, self._page_of,
                    self._pages, self.n_pages, self._rows, self.n_rows, keys, vals, cols, sign, start, lo, hi)
            if status == 0:
                return None
            if status == 1:
                self._grow()
            elif not self._widen(group):
                return start

    def _values(self, delta: Delta) -> tuple[np.ndarray, np.ndarray]:
        """A delta's channels as one (n, m) int64 (or int32) matrix and, per matrix column, its memory column.

        When every channel is a column slice of one 2-D array (a contributor's rows, e.g. the geometry
        delta's (n, 4) A N F O), that array is used as is; otherwise the channels are concatenated."""
        names = sorted(delta.channels)
        arrs = [delta.channels[n] for n in names]
        mcols = np.concatenate([self._cols(n, a.shape[1]) for n, a in zip(names, arrs)])
        matrix, src = _column_matrix(arrs, len(delta))
        if len(np.unique(src)) < len(src):  # a column of the base read twice: one matrix column a memory column
            return np.ascontiguousarray(np.concatenate(arrs, axis=1)), mcols
        cols = np.full(matrix.shape[1], -1, np.int64)
        cols[src] = mcols
        return matrix, cols

    def _grow(self) -> None:
        """Make room: rehash a table past half full; double full block, page or row storage (a copy only
        past the reservation)."""
        if 2 * (self.n_blocks + 1) > self._table_keys.shape[0]:
            self._table_keys, self._table_slots = _rehash(self._block_keys, self.n_blocks,
                                                           2 * self._table_keys.shape[0])
        if self.n_blocks >= self._block_keys.shape[0]:
            cap = 2 * self._block_keys.shape[0]
            self._block_keys = _grown(self._block_keys, self.n_blocks, cap)
            self._geo = _grown(self._geo, self.n_blocks, cap)
            if self.sparse_width:
                self._page_of = _grown(self._page_of, self.n_blocks, cap)
        if self.sparse_width and self.n_pages >= self._pages.shape[0]:
            self._pages = _grown(self._pages, self.n_pages, 2 * self._pages.shape[0])
        if self.sparse_width and self.n_rows >= self._rows.shape[0]:
            self._rows = _grown(self._rows, self.n_rows, 2 * self._rows.shape[0])

    def _widen(self, group: str) -> bool:
        """int32 -> int64 storage of ``group`` (a sum left int32); False when it is int64 already."""
        if (self._geo if group == "dense" else self._rows).dtype == np.int64:
            return False
        if group == "dense":
            self._geo = _grown(self._geo, self.n_blocks, self._geo.shape[0], np.int64)
        else:
            self._rows = _grown(self._rows, self.n_rows, self._rows.shape[0], np.int64)
        return True

    @staticmethod
    def _refuse(group: str, key) -> None:
        from ..geometry.lattice import unpack_keys

        raise PanovoccError(f"a {group} memory channel at voxel {unpack_keys(np.array([key]))[0].tolist()} would "
                            "pass the int64 range: the delta is refused (a value is never wrapped)")

    # -- reads -----------------------------------------------------------------------------------
    def _channels_at(self, loc: np.ndarray, names, stored: bool = False) -> dict:
        """Channels ``names`` at storage locations ``loc`` (n,) (-1: zeros) as name -> (n, width) int64
        (``stored``: in the group's storage type, int32 until a sum widened it: the same values, half the
        bytes, for a whole-memory read such as ``memory.npz``'s)."""
        loc = np.ascontiguousarray(loc, np.int64)
        out = {}
        dense = sparse = None
        for name in names:
            spec = self.spec(name)
            c0 = self.offsets[name]
            if name in GEOMETRY_NAMES:
                if dense is None:
                    dense = np.zeros((len(loc), self.dense_width), self._geo.dtype if stored else np.int64)
                    _dense_at(self._geo, loc, dense)
                d0 = self._dense_col[c0]
                out[name] = dense[:, d0:d0 + spec.width]
            else:
                if sparse is None:
                    sparse = np.zeros((len(loc), self.sparse_width), self._rows.dtype if stored else np.int64)
                    _sparse_at(self._page_of, self._pages, self._rows, loc, sparse)
                s0 = self._sparse_col[c0]
                out[name] = sparse[:, s0:s0 + spec.width]
        return out

    def gather(self, keys: np.ndarray, names=None) -> dict:
        """Channel values at voxel ``keys`` (n,) int64 -> dict name -> (n, width) int64 (zeros if absent);
        ``names``: those channels only (default all)."""
        keys = np.ascontiguousarray(keys, dtype=np.int64)
        loc = np.empty(len(keys), np.int64)
        _locate(self._table_keys, self._table_slots, keys, loc)
        return self._channels_at(loc, [c.name for c in self.specs] if names is None else list(names))

    def _split(self, rows: np.ndarray) -> dict:
        return {c.name: rows[:, self.offsets[c.name]: self.offsets[c.name] + c.width] for c in self.specs}

    def nonzero(self) -> tuple[np.ndarray, NonzeroChannels]:
        """Every voxel with a non-zero channel, in key order.

        Returns
        -------
        keys : (n,) int64 sorted, read-only
        channels : :class:`NonzeroChannels`, name -> (n, width) int64, each read when first asked for
        """
        if self._nonzero is None:  # a save and an export of the same memory scan it once
            # in key order as scanned, x-slab by x-slab (MemoryChunks): no sort, no unsorted copy
            loc = np.concatenate([np.zeros(0, np.int64)] + [c for _, c in MemoryChunks(self)._plan], dtype=np.int64)
            keys = np.empty(len(loc), np.int64)
            _keys_at(self._block_keys, loc, keys)
            keys.flags.writeable = loc.flags.writeable = False
            self._nonzero = (keys, loc)
        keys, loc = self._nonzero
        return keys, NonzeroChannels(self, loc)

    def nonzero_slabs(self, max_voxels: int = 1 << 18):
        """:meth:`nonzero` a slab of the key space at a time: yields ``(keys, locations)`` of the voxels with
        a non-zero channel whose blocks lie in a run of block x-indices of at most about ``max_voxels``
        allocated voxels (one block x-index at least), the slabs in key order and each sorted, so that
        their concatenation is :meth:`nonzero`'s keys. For :class:`NonzeroChannels` (``NonzeroChannels(memory,
        locations)``); the temporaries are a slab's, not the memory's."""
        bkeys = self._block_keys[:self.n_blocks]
        if len(bkeys) == 0:
            return
        order = np.argsort(bkeys, kind="stable").astype(np.int64)  # block keys sort x-major like voxel keys
        bx, by, _ = unpack_index(bkeys[order])
        bx, by = np.ascontiguousarray(bx, np.int64), np.ascontiguousarray(by, np.int64)
        starts = np.flatnonzero(np.r_[True, bx[1:] != bx[:-1]])  # the first block of each block x-index
        ends = np.r_[starts[1:], len(order)]
        per_slab = max(int(max_voxels) // BLOCK_VOXELS, 1)
        a = 0
        while a < len(starts):
            b = a + 1
            while b < len(starts) and ends[b] - starts[a] <= per_slab:
                b += 1
            b0, b1 = int(starts[a]), int(ends[b - 1])
            loc = np.empty((b1 - b0) * BLOCK_VOXELS, np.int64)  # in key order as scanned: no sort
            cnt = _ordered_nonzero(order, bx, by, self._geo, self._page_of, self._pages, self._rows,
                                   bool(self.sparse_width), b0, b1, 0, BLOCK, loc)
            loc = loc[:cnt].copy()
            keys = np.empty(cnt, np.int64)
            _keys_at(self._block_keys, loc, keys)
            yield keys, loc
            a = b

    def to_arrays(self, sparse: bool = False) -> dict:
        """The canonical on-disk form (see docs/mapping.md): equal sums give equal arrays. ``sparse``: the
        sparse group's channels as :class:`~panovocc_cli.io.mapstore.SparseRows` over the voxels that hold
        a row (what ``memory.npz`` is written from, to the same bytes, without the (n, width) arrays)."""
        keys, ch = self.nonzero()
        if sparse and self.sparse_width:
            return self._to_sparse_arrays(keys, ch)
        out = self._header(keys)
        for name in ch:
            out[f"ch_{name}"] = ch[name]
        return out

    def _to_sparse_arrays(self, keys, ch: NonzeroChannels) -> dict:
        from ..io.mapstore import SparseRows

        has = np.zeros(len(keys), np.bool_)
        _has_row(self._page_of, self._pages, ch._loc, has)
        pos = np.flatnonzero(has)
        dense = [s.name for s in self.specs if s.name in GEOMETRY_NAMES]
        rest = [s.name for s in self.specs if s.name not in GEOMETRY_NAMES]
        out = self._header(keys)
        got = self._channels_at(ch._loc, dense, stored=True)
        at = self._channels_at(ch._loc[pos], rest, stored=True)
        for s in self.specs:
            out[f"ch_{s.name}"] = got[s.name] if s.name in got else SparseRows(pos, at[s.name], len(keys))
        return out

    def chunked(self, chunk: int | None = None) -> MemoryChunks:
        """The canonical arrays read a key range at a time (:class:`MemoryChunks`: what ``memory.npz`` is
        streamed from, to the same bytes as :meth:`to_arrays`)."""
        return MemoryChunks(self, chunk)

    def _header(self, keys=None) -> dict:
        return {**({} if keys is None else {"keys": keys}), "voxel_size": np.float64(self.voxel_size),
                "channel_names": np.array([c.name for c in self.specs], dtype=np.str_),
                "channel_widths": np.array([c.width for c in self.specs], dtype=np.int64),
                "channel_kinds": np.array([c.kind for c in self.specs], dtype=np.str_),
                "fixed_scale": np.int64(FIXED_SCALE)}

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
            for group in (True, False):  # the geometry, then the rest: rows only where a value is non-zero
                ch = {s.name: z[f"ch_{s.name}"] for s in specs if (s.name in GEOMETRY_NAMES) == group}
                full = {k: v for k, v in ch.items() if not hasattr(v, "rows")}
                for a in range(0, len(keys) if full else 0, LOAD_CHUNK):  # LOAD_CHUNK rows at a time
                    mem.add(Delta(keys[a:a + LOAD_CHUNK], {k: v[a:a + LOAD_CHUNK] for k, v in full.items()}))
                for names in _same_rows({k: v for k, v in ch.items() if hasattr(v, "rows")}):
                    rows_all = ch[names[0]].rows  # io.mapstore.SparseRows: their rows only, in one pass
                    for a in range(0, len(rows_all), LOAD_CHUNK):
                        mem.add(Delta(keys[rows_all[a:a + LOAD_CHUNK]],
                                      {k: ch[k].values[a:a + LOAD_CHUNK] for k in names}))
        except KeyError as e:
            raise PanovoccError(f"memory file lacks {e}", where) from None
        return mem

    def __len__(self) -> int:
        return len(self.nonzero()[0])
