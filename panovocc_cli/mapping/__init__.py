"""Geometric mapping: the persistent hashed voxel memory, the PSVF kernel, free-space carving, the
reversible per-frame deltas, export, and the ``map`` / ``revise`` / ``bench`` pipelines."""

import numba as _numba

# OpenMP first (libgomp ships with the toolkit's setup), never TBB (an old TBB only produces a warning).
_numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]
