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
