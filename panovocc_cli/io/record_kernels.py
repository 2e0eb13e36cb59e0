"""Compiled passes of the delta record's encoding and decoding (:mod:`.mapstore`): each gives what the
numpy formulation beside it in mapstore gives, element for element (int64 arithmetic wraps as numpy's
does), in one pass over the rows instead of several temporaries. A revision encodes and decodes one
record a frame, and these passes were ~20 ms of its ~160 ms CPU a frame (docs/mapping.md, "Building
revise, fifth pass"). Every kernel is tested against the numpy formulation (tests/io/test_record_kernels.py).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_I64_MIN = np.iinfo(np.int64).min


@nb.njit(cache=True, nogil=True)
def factor_rows(x, f, den):
    """``channel = f * m / den`` per row (:func:`.mapstore._factored`): x (n, w) int64, f (n,) int64, den
    int64. Returns (ok, m (n, w) int64): m = ``x * den // f`` where f != 0, else 0; ok when ``m * f`` equals
    ``x * den`` everywhere (int64 products wrap, as numpy's do). Stops at the first row that does not hold
    (m is then unused)."""
    n, w = x.shape
    m = np.zeros((n, w), np.int64)
    for r in range(n):
        fv = f[r]
        for c in range(w):
            num = x[r, c] * den
            if fv == 0:
                if num != 0:
                    return False, m
                continue
            if fv == -1:
                q = -num  # numpy's floor division gives INT64_MIN // -1 = INT64_MIN, as the negation wraps
            else:
                q = num // fv
            if q * fv != num:
                return False, m
            m[r, c] = q
    return True, m


@nb.njit(cache=True, nogil=True)
def nonzero_rows(a):
    """The positions (int64, ascending) of the rows of ``a`` (n, w) that hold a non-zero value:
    ``np.flatnonzero(a.any(axis=1))``."""
    n, w = a.shape
    keep = np.zeros(n, np.bool_)
    k = 0
    for r in range(n):
        for c in range(w):
            if a[r, c] != 0:
                keep[r] = True
                k += 1
                break
    out = np.empty(k, np.int64)
    j = 0
    for r in range(n):
        if keep[r]:
            out[j] = r
            j += 1
    return out


@nb.njit(cache=True, nogil=True)
def key_gaps(keys, gap_max, jump_mark):
    """A part's keys (n,) int64 as (gaps (n - 1,) int16, jumps int64): the gap to the next key, or
    ``jump_mark`` where ``|gap| > gap_max``, those gaps kept apart in order (:func:`.mapstore.delta_arrays`:
    ``np.where(np.abs(g) > gap_max, jump_mark, g).astype(np.int16)`` and ``g[np.abs(g) > gap_max]``)."""
    n = keys.shape[0]
    m = max(n - 1, 0)
    gaps = np.empty(m, np.int16)
    k = 0
    for i in range(m):
        g = keys[i + 1] - keys[i]
        if (-g if g < 0 else g) > gap_max:  # -INT64_MIN wraps to itself, as np.abs does: not a jump
            k += 1
    jumps = np.empty(k, np.int64)
    k = 0
    for i in range(m):
        g = keys[i + 1] - keys[i]
        if (-g if g < 0 else g) > gap_max:
            gaps[i] = jump_mark
            jumps[k] = g
            k += 1
        else:
            gaps[i] = np.int16(g)  # truncated, as astype(np.int16) does
    return gaps, jumps


@nb.njit(cache=True, nogil=True)
def keys_from_gaps(first, gaps, jumps, jump_mark):
    """Inverse of :func:`key_gaps`: keys (len(first) + len(gaps),) int64, the running sum of ``first`` (0 or 1
    values) then the gaps, each ``jump_mark`` taking the next of ``jumps``. Returns (ok, keys); ok False when
    the number of marks differs from ``len(jumps)`` (a damaged record)."""
    n0 = first.shape[0]
    out = np.empty(n0 + gaps.shape[0], np.int64)
    s = np.int64(0)
    for i in range(n0):
        s += first[i]
        out[i] = s
    k = 0
    for i in range(gaps.shape[0]):
        g = np.int64(gaps[i])
        if g == jump_mark:
            if k >= jumps.shape[0]:
                return False, out
            g = jumps[k]
            k += 1
        s += g
        out[n0 + i] = s
    return k == jumps.shape[0], out


@nb.njit(cache=True, nogil=True)
def scatter_rows(n, row_gaps, vals):
    """An (n, w) int64 array, zero but at rows ``cumsum(row_gaps)`` which hold ``vals`` (m, w) (a channel
    stored as its non-zero rows, :func:`.mapstore._decode_channels`). Returns (ok, array); ok False when a
    row falls outside 0..n-1 (a damaged record)."""
    m, w = vals.shape
    out = np.zeros((n, w), np.int64)
    r = np.int64(0)
    for i in range(m):
        r += np.int64(row_gaps[i])
        if r < 0 or r >= n:
            return False, out
        for c in range(w):
            out[r, c] = vals[i, c]
    return True, out


@nb.njit(cache=True, nogil=True)
def from_planes(planes):
    """Byte planes (k, m) uint8 (every value's lowest byte, then every value's next byte...; k = 2, 4 or 8) as
    the m little-endian signed values they store, int64 (:func:`.mapstore._unshuffled`)."""
    k, m = planes.shape
    out = np.empty(m, np.int64)
    shift = 64 - 8 * k
    for i in range(m):
        v = np.uint64(0)
        for b in range(k):
            v |= np.uint64(planes[b, i]) << np.uint64(8 * b)
        out[i] = (np.int64(v << np.uint64(shift))) >> shift  # sign-extended from k bytes
    return out


@nb.njit(cache=True, nogil=True)
def to_planes(a, k):
    """Inverse of :func:`from_planes`: the values of ``a`` (any shape, integers of k bytes, C order) as byte
    planes (k, a.size) uint8 (:func:`.mapstore._shuffled`)."""
    flat = a.reshape(-1)
    m = flat.shape[0]
    out = np.empty((k, m), np.uint8)
    for i in range(m):
        v = np.int64(flat[i])
        for b in range(k):
            out[b, i] = np.uint8((v >> (8 * b)) & 0xFF)
    return out
