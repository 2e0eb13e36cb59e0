"""The compiled steps of GSC's diffusion (:mod:`.gsc`), in a module of their own so that importing
:mod:`.gsc` (its parameters are part of every mapping config) does not import numba."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)  # releases the GIL: revise exports while memory.npz is written
def iterate(indptr, indices, data, q, anchor, inv, live, lam, iterations):
    """``iterations`` steps of ``q <- (anchor + lam (W_bar q)) inv`` on the live rows (the others keep q), W_bar
    a CSR matrix (indptr, indices, data) float32: each step in one pass over the rows, into a second buffer.
    The same float32 operations in the same order as scipy's CSR product (``Wb @ q``: each row's entries
    added in stored order to a row of zeros) followed by ``*= lam``, ``+= anchor``, ``*= inv``, so the result
    is the same bit for bit (tests/semantics/test_gsc.py); the product's (n, C) temporary and the three
    passes over it are gone."""
    n, c = q.shape
    a = q
    b = np.empty_like(q)
    for _ in range(iterations):
        for i in range(n):
            if live[i]:
                for k in range(c):
                    b[i, k] = np.float32(0.0)
                for jj in range(indptr[i], indptr[i + 1]):
                    w = data[jj]
                    j = indices[jj]
                    for k in range(c):
                        b[i, k] += w * a[j, k]
                for k in range(c):
                    b[i, k] = (b[i, k] * lam + anchor[i, k]) * inv[i]
            else:
                for k in range(c):
                    b[i, k] = a[i, k]
        a, b = b, a
    return a


@nb.njit(cache=True, nogil=True)
def edge_terms(i, j, axis, g, nh, col, s_g, two_s_t):
    """The per-edge arguments of GSC's affinity (:func:`.gsc._affinity`), gathered in one pass over the edges
    instead of one numpy temporary per operation: ``-|g_i - g_j| / s_g``; ``max(n_i . n_j, 0)`` and whether both
    voxels have a normal; ``-((n_i)_a^2 + (n_j)_a^2) / (2 s_t)``; ``||c_i - c_j||^2`` (NaN where a colour is
    unknown). The float32 operations of the numpy expressions they replace, in the same order (the sums over
    the three components left to right, as ``einsum`` adds them; ``maximum`` keeping ``-0.0`` as numpy's does),
    so the values are the same bit for bit (tests/semantics/test_semantics_gsc.py); the exponentials stay
    numpy's."""
    m = i.size
    xg = np.empty(m, np.float32)
    dn = np.empty(m, np.float32)
    has = np.empty(m, np.bool_)
    xt = np.empty(m, np.float32)
    d2 = np.empty(m, np.float32)
    zero = np.float32(0.0)
    for e in range(m):
        a = i[e]
        b = j[e]
        xg[e] = -abs(g[a] - g[b]) / s_g
        na0, na1, na2 = nh[a, 0], nh[a, 1], nh[a, 2]
        nb0, nb1, nb2 = nh[b, 0], nh[b, 1], nh[b, 2]
        dot = na0 * nb0 + na1 * nb1 + na2 * nb2
        dn[e] = dot if (dot >= zero or np.isnan(dot)) else zero
        has[e] = (abs(na0) + abs(na1) + abs(na2) > zero) and (abs(nb0) + abs(nb1) + abs(nb2) > zero)
        k = axis[e]
        ai = nh[a, k]
        aj = nh[b, k]
        xt[e] = -(ai * ai + aj * aj) / two_s_t
        c0 = col[a, 0] - col[b, 0]
        c1 = col[a, 1] - col[b, 1]
        c2 = col[a, 2] - col[b, 2]
        d2[e] = c0 * c0 + c1 * c1 + c2 * c2
    return xg, dn, has, xt, d2


@nb.njit(cache=True, nogil=True)
def transition_csr(n, i, j, w):
    """GSC's row-normalised affinity matrix as CSR arrays, and its row sums (:func:`.gsc.transition_matrix`).

    Each edge with ``w > 0`` enters in both directions, first every kept edge as (i, j), then every one as
    (j, i); a row's degree is the float64 sum of its weights in that order (``np.bincount``'s), rounded to
    float32, and each entry is ``w / degree`` in float32. A row holds its entries by increasing column (scipy's
    canonical CSR, which its COO constructor makes), and its sum is ``csr.sum(axis=1)``'s: numpy's float32
    ``add.reduceat`` of the row, its first entry plus the sum of the others in stored order (numpy sums pairwise
    only from 9 entries on; a row of the 6-neighbour graph has at most 6). Returns (indptr, indices) int64, data
    float32, rowsum float32."""
    m = i.size
    deg = np.zeros(n, np.float64)
    start = np.zeros(n + 1, np.int64)
    for e in range(m):
        if w[e] > 0:
            deg[i[e]] += np.float64(w[e])
            start[i[e] + 1] += 1
    for e in range(m):
        if w[e] > 0:
            deg[j[e]] += np.float64(w[e])
            start[j[e] + 1] += 1
    for r in range(n):
        start[r + 1] += start[r]
    d32 = deg.astype(np.float32)
    nnz = start[n]
    indices = np.empty(nnz, np.int64)
    data = np.empty(nnz, np.float32)
    fill = start[:n].copy()
    for side in range(2):
        for e in range(m):
            if w[e] > 0:
                r, c = (i[e], j[e]) if side == 0 else (j[e], i[e])
                k = fill[r]
                indices[k] = c
                data[k] = w[e] / d32[r]
                fill[r] = k + 1
    rowsum = np.zeros(n, np.float32)
    for r in range(n):
        for a in range(start[r] + 1, start[r + 1]):  # insertion sort by column: a row has at most 6 entries
            c, v = indices[a], data[a]
            b = a - 1
            while b >= start[r] and indices[b] > c:
                indices[b + 1] = indices[b]
                data[b + 1] = data[b]
                b -= 1
            indices[b + 1] = c
            data[b + 1] = v
        if start[r + 1] > start[r]:  # add.reduce's order: the first entry plus the sum of the rest
            s = np.float32(0.0)
            for a in range(start[r] + 1, start[r + 1]):
                s += data[a]
            rowsum[r] = data[start[r]] + s
    return start, indices, data, rowsum
