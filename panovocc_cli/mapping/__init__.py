"""Geometric mapping: the persistent hashed voxel memory, the PSVF kernel, free-space carving, the
reversible per-frame deltas, export, and the ``map`` / ``revise`` / ``bench`` pipelines.

numba's threading layer is chosen in ``panovocc_cli/__init__.py`` (OpenMP first, never TBB first)."""
