"""Sparse scored voxels ``.npz``: what an external model's sparse output (Gaussians voxelised, a point list with
class scores) is converted to before ``panovocc baselines merge`` (docs/baselines.md, "Imported baselines").

=============  ===================  ================================================================
key            shape, dtype         meaning
=============  ===================  ================================================================
voxel_size     () float             lattice edge h, metres
centers        (n, 3) float         world coordinates (metres, +Z up) of each occupied voxel: its centre, or
                                    any point inside it (the voxel is ``floor(p / h)``, CONVENTIONS.md)
class_names    (C,) str             the classes (no ``empty`` entry)
scores         (n, C) float         per-class confidences of each voxel (its class: the argmax, its
                                    confidence: the max) -- or, instead:
labels         (n,) int             position in ``class_names`` of each voxel's class (-1: no class), with
confidence     (n,) float           that class's confidence
=============  ===================  ================================================================

Either ``scores``, or ``labels`` and ``confidence``. Confidences are compared across the inputs of one merge,
so they should be on one scale (probabilities). Loaded with ``allow_pickle=False``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..geometry.lattice import point_to_index
from .npz import check_npz, write_npz

SPARSE_KEYS = ("centers", "voxel_size", "class_names")


def is_sparse_npz(path: str | Path) -> bool:
    """Whether ``path`` is an ``.npz`` with the sparse voxel keys (``centers``), not a grid."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return "centers" in z.files
    except Exception:  # not a readable npz: the reader says why
        return False


def read_sparse_voxels(path: str | Path):
    """Read and check a sparse voxels ``.npz`` -> :class:`panovocc_cli.baselines.merge.SparseVoxels`-shaped
    tuple ``(index (n, 3) int64, labels (n,) int64, confidence (n,) float64, voxel_size, class_names)``."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("sparse voxels file not found", path)
    check_npz(path, "a sparse voxels .npz (centers, voxel_size, class_names)")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in SPARSE_KEYS if k not in z.files]
            if missing:
                raise PanovoccError(f"missing keys {missing} (expected centers, voxel_size, class_names and scores, "
                                    "or labels and confidence)", path)
            d = {k: z[k] for k in z.files}
    except PanovoccError:
        raise
    except Exception as e:
        raise PanovoccError(f"cannot read sparse voxels .npz ({type(e).__name__}: {e})", path) from None
    h = float(np.asarray(d["voxel_size"]).reshape(-1)[0]) if np.asarray(d["voxel_size"]).size == 1 else float("nan")
    if not (np.isfinite(h) and h > 0):
        raise PanovoccError(f"voxel_size must be one positive number, got {d['voxel_size']!r}", path)
    names = [str(c) for c in np.asarray(d["class_names"]).reshape(-1)]
    c = np.asarray(d["centers"], np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or not np.all(np.isfinite(c)):
        raise PanovoccError(f"centers must be finite (n, 3), got shape {c.shape}", path)
    n = len(c)
    if "scores" in d:
        s = np.asarray(d["scores"], np.float64)
        if s.shape != (n, len(names)) or not np.all(np.isfinite(s)):
            raise PanovoccError(f"scores must be finite (n, C) = ({n}, {len(names)}), got {s.shape}", path)
        labels = s.argmax(axis=1) if len(names) else np.full(n, -1)
        conf = s.max(axis=1) if len(names) else np.zeros(n)
    elif "labels" in d and "confidence" in d:
        labels = np.asarray(d["labels"])
        conf = np.asarray(d["confidence"], np.float64)
        if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
            raise PanovoccError(f"labels must be (n,) = ({n},) integers, got {labels.dtype} {labels.shape}", path)
        if conf.shape != (n,) or not np.all(np.isfinite(conf)):
            raise PanovoccError(f"confidence must be finite (n,) = ({n},), got {conf.shape}", path)
        if n and (labels.min() < -1 or labels.max() >= len(names)):
            raise PanovoccError(f"labels must be -1 or positions in class_names (0..{len(names) - 1})", path)
    else:
        raise PanovoccError("neither scores nor labels + confidence (expected one of the two)", path)
    return point_to_index(c, h), np.asarray(labels, np.int64), np.asarray(conf, np.float64), h, names


def write_sparse_voxels(path: str | Path, centers: np.ndarray, voxel_size: float, class_names, *,
                        scores: np.ndarray | None = None, labels: np.ndarray | None = None,
                        confidence: np.ndarray | None = None) -> None:
    """Write a sparse voxels ``.npz`` (module docstring): ``scores``, or ``labels`` and ``confidence``."""
    arrays = {"centers": np.asarray(centers, np.float64).reshape(-1, 3), "voxel_size": np.float64(voxel_size),
              "class_names": np.array([str(c) for c in class_names], dtype=np.str_)}
    if scores is not None:
        arrays["scores"] = np.asarray(scores, np.float64)
    else:
        arrays["labels"] = np.asarray(labels, np.int64)
        arrays["confidence"] = np.asarray(confidence, np.float64)
    write_npz(path, arrays)
