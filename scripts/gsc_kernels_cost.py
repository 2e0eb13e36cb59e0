"""What GSC's compiled edge affinity and transition matrix cost against the numpy / scipy forms they replaced
(docs/mapping.md, "GSC's affinity and matrix compiled"): the same random inputs, five calls of each, the
best time, and the outputs compared bit for bit.

    PYTHONPATH=tests python scripts/gsc_kernels_cost.py
"""

from __future__ import annotations

import time

import numpy as np
from semantics_reference import affinity_numpy, transition_scipy

import panovocc_cli.runtime as rt
from panovocc_cli.geometry.lattice import pack_keys
from panovocc_cli.semantics.gsc import GSCParams, _affinity, neighbour_edges, transition_matrix, unit_rows


def best(f, calls: int = 5) -> float:
    f()
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return 1e3 * min(times)


def main() -> None:
    rt.setup()
    rng = np.random.default_rng(0)
    n, m, p = 300_000, 1 << 20, GSCParams()
    i = np.sort(rng.integers(0, n, m)).astype(np.int32)
    j = np.minimum(i + rng.integers(1, 3000, m), n - 1).astype(np.int32)
    axis = rng.integers(0, 3, m).astype(np.int8)
    g = rng.normal(size=n).astype(np.float32)
    nh = unit_rows(rng.normal(size=(n, 3)))
    col = (rng.random((n, 3)) * 255).astype(np.float32)
    same = np.array_equal(_affinity(i, j, axis, g, nh, col, p).view(np.uint32),
                          affinity_numpy(i, j, axis, g, nh, col, p).view(np.uint32))
    t_numpy = best(lambda: affinity_numpy(i, j, axis, g, nh, col, p))
    t_compiled = best(lambda: _affinity(i, j, axis, g, nh, col, p))
    print(f"affinity, {m:,} edges of {n:,} voxels: numpy {t_numpy:.1f} ms, compiled {t_compiled:.1f} ms, "
          f"same bits: {same}")
    idx = np.unique(rng.integers(0, 60, (200_000, 3)), axis=0)
    idx = idx[np.argsort(pack_keys(idx))]
    e_i, e_j, _ = neighbour_edges(idx)
    w = rng.random(e_i.size).astype(np.float32)
    w[rng.random(e_i.size) < 0.2] = 0
    k = len(idx)
    same = all(np.array_equal(a.view(np.uint8), b.view(np.uint8))
               for a, b in zip(transition_matrix(k, e_i, e_j, w), transition_scipy(k, e_i, e_j, w)))
    t_scipy = best(lambda: transition_scipy(k, e_i, e_j, w))
    t_compiled = best(lambda: transition_matrix(k, e_i, e_j, w))
    print(f"transition matrix, {e_i.size:,} edges of {k:,} voxels: scipy {t_scipy:.1f} ms, "
          f"compiled {t_compiled:.1f} ms, same bits: {same}")


if __name__ == "__main__":
    main()
