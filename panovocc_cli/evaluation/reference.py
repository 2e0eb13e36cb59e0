"""Reference labellings of a prediction's geometry: what its occupied voxels would score with perfect
labels (the ceiling of any labelling of that geometry, docs/mapping.md "Semantic memory")."""

from __future__ import annotations

import numpy as np

from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from .align import check_same_voxel_size, resample_onto


def relabel_from_ground_truth(pred: Grid, gt: Grid, max_dist_vox: float = 0.0) -> Grid:
    """Reference "perfect labels" for a prediction's geometry: its occupied voxels labelled by the truth.

    Each occupied voxel of ``pred`` (label not 0/255) takes the ground-truth class at the same voxel when
    the truth has a class there (1..253). Elsewhere (the truth says empty, unknown or 254, or does not
    cover the voxel: a geometric false positive) it takes the class of the nearest ground-truth class
    voxel within ``max_dist_vox`` voxels (Euclidean), else 254.

    * ``max_dist_vox = 0``: the ceiling of any labelling of this occupied set under the FreeOcc protocol
      (a voxel the truth does not hold gets no class, so it adds no class false positive);
    * ``max_dist_vox = 2`` (the mapper's own transfer bound): what per-pixel ground-truth labels binned
      into the voxels give; a voxel of a thickened surface takes the class of the surface it belongs to,
      exactly as the mapper labels it from the pixels that fell into it.

    Free and unobserved voxels are unchanged.

    Parameters
    ----------
    pred, gt : Grid on the same lattice (same voxel size)
    max_dist_vox : float >= 0, voxels

    Returns
    -------
    Grid, ``pred``'s box, class names = ``gt.class_names``
    """
    from scipy.spatial import cKDTree

    check_same_voxel_size(pred, gt, "prediction and ground truth")
    truth = resample_onto(gt, pred, fill=UNKNOWN)
    occ = (pred.labels != EMPTY) & (pred.labels != UNKNOWN)
    has_class = (truth != EMPTY) & (truth != UNKNOWN) & (truth != OCCUPIED_UNKNOWN_CLASS)
    out = pred.labels.copy()
    out[occ] = np.where(has_class[occ], truth[occ], OCCUPIED_UNKNOWN_CLASS)
    need = np.argwhere(occ & ~has_class)
    src = np.argwhere((gt.labels != EMPTY) & (gt.labels != UNKNOWN) & (gt.labels != OCCUPIED_UNKNOWN_CLASS))
    if max_dist_vox > 0 and len(need) and len(src):
        tree = cKDTree((src + gt.index0).astype(np.float64))
        dist, nn = tree.query((need + pred.index0).astype(np.float64), k=1,
                              distance_upper_bound=float(max_dist_vox) + 1e-9)
        ok = np.isfinite(dist)
        s_ijk = src[nn[ok]]
        out[tuple(need[ok].T)] = gt.labels[tuple(s_ijk.T)]
    return Grid(out, pred.origin, pred.voxel_size, list(gt.class_names))
