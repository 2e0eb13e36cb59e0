"""How close a lifted ground truth comes to the mesh ground truth of the same scene (docs/gt.md, the
protocol's own measurement). Pure maths on two grids of the same lattice."""

from __future__ import annotations

import numpy as np

from ..classes import canonical_name
from ..evaluation.align import check_same_voxel_size, resample_onto
from ..evaluation.metrics import evaluate
from ..grid import OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid


def _name_ids(grid: Grid, names: dict[str, int]) -> np.ndarray:
    """Per label id 0..255 of ``grid``: an id of its canonical class name in ``names`` (grown), -1 for none."""
    out = np.full(256, -1, np.int64)
    for k, n in enumerate(grid.class_names):
        if 0 < k < OCCUPIED_UNKNOWN_CLASS:
            out[k] = names.setdefault(canonical_name(n), len(names))
    return out


def label_agreement(lifted: Grid, mesh: Grid) -> dict[str, float | int]:
    """Label agreement of the voxels occupied in both grids (classes matched by canonical name).

    Returns
    -------
    dict: ``common`` voxels occupied in both; ``agree`` percent of them with the same class (a lifted 254
    counts as a disagreement); ``classed`` percent of them the lifted grid gives a class (not 254);
    ``agree_classed`` percent agreement among those.
    """
    check_same_voxel_size(lifted, mesh, "lifted and mesh ground truths")
    a = resample_onto(lifted, mesh, fill=UNKNOWN).astype(np.int64)
    b = mesh.labels.astype(np.int64)
    both = (a > 0) & (a < UNKNOWN) & (b > 0) & (b < UNKNOWN)
    names: dict[str, int] = {}
    na, nb = _name_ids(lifted, names)[a[both]], _name_ids(mesh, names)[b[both]]
    classed = na >= 0
    same = classed & (na == nb)
    n = int(both.sum())
    pct = lambda x, d: 100.0 * x / d if d else float("nan")  # noqa: E731
    return {"common": n, "agree": pct(int(same.sum()), n), "classed": pct(int(classed.sum()), n),
            "agree_classed": pct(int(same.sum()), int(classed.sum()))}


def compare_to_mesh(lifted: Grid, mesh: Grid, classes: str = "eval8") -> dict[str, float | int]:
    """Scores of the lifted grid taken as a prediction of the mesh ground truth, plus label agreement.

    Returns
    -------
    dict (percent): ``iou``, ``miou`` (FreeOcc mask: the mesh grid's every voxel, lifted 255 = not occupied),
    ``iou_observed``, ``miou_observed`` (only voxels the lifted grid observed), and :func:`label_agreement`'s keys.
    """
    r = evaluate([(lifted, mesh)], classes)
    f, o = r["freeocc"], r["observed"]
    return {"iou": f.iou, "miou": f.miou, "iou_observed": o.iou, "miou_observed": o.miou,
            **label_agreement(lifted, mesh)}
