"""Occupancy IoU and semantic mIoU under the FreeOcc protocol (CONVENTIONS.md, "Scoring").

* Scored voxels: every ground-truth voxel whose label is not 255. A prediction outside the
  ground-truth grid is dropped; a ground-truth voxel the prediction does not cover counts as
  predicted not-occupied (mask ``freeocc``, the headline). Mask ``observed`` further drops the
  voxels the prediction left at 255 or does not cover.
* Occupied = a label other than 0 and 255 (254, occupied with no class, is occupied).
* IoU = TP / (TP + FP + FN) on occupied/not-occupied; per-class IoU the same on one class, classes
  matched by canonical **name** (:func:`panovocc_cli.classes.canonical_name`) across the two grids.
* mIoU (the headline), as FreeOcc's released evaluation code computes it (``SSCMetricsTorch`` in
  ``src/scannet_utils/eval_utils.py``, averaged in ``scripts/src/eval_occ_replica.py``): the mean,
  over **every** class of the chosen set, of ``tp / (tp + fp + fn + 1e-5)`` (their ``_safe_div``
  adds a further 1e-8 to the denominator; so do we). A class absent from the ground truth and from
  the prediction scores 0, not NaN, and counts in the mean.
* ``miou_present``: the mean of the exact per-class IoUs over the classes of the set **present in
  the ground truth** (at least one scored ground-truth voxel carries the class), reported beside the
  headline and labelled wherever the two differ (some class of the set is absent).
* Several pairs are pooled by summing counts before dividing.
* Undefined ratios (0 / 0: empty union) are NaN, shown as ``n/a`` and written as JSON ``null``; an
  empty prediction against a non-empty ground truth has IoU 0 (defined).

All scores are **percent** (0..100), like the paper's tables.

Everything is counted from one ``np.bincount`` over (gt id, pred id) pairs on the grids' overlap,
so a 10-million-voxel pair scores in a fraction of a second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from ..classes import EMPTY, UNLABELED, canonical_name, parse_class_set
from ..grid import UNKNOWN, Grid
from .align import overlap

MASKS: tuple[str, ...] = ("freeocc", "observed")
HEADLINE_MASK = "freeocc"
MASK_LABELS = {"freeocc": "FreeOcc (headline)", "observed": "observed only"}

# FreeOcc's per-class IoU: ``_safe_div(tps, tps + fps + fns + 1e-5)`` with ``_safe_div(num, den, eps=1e-8)
# = num / (den + eps)``. Kept as two constants, added in their order, so the float64 result is theirs bit
# for bit.
FREEOCC_CLASS_EPS = 1e-5
FREEOCC_SAFE_DIV_EPS = 1e-8


@dataclass
class Counts:
    """Voxel counts of one or several (pooled) pairs under one mask.

    Attributes
    ----------
    tp, fp, fn, tn : int
        Occupancy counts on the scored voxels.
    classes : dict[str, (3,) int64]
        Per class name (canonical, every class either side names): ``[tp, fp, fn]``.
    gt_names : list[str]
        Canonical names the ground-truth grids carry, in their order (used by class set ``all``).
    pairs : int
        Number of pairs pooled.
    """

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    classes: dict[str, np.ndarray] = field(default_factory=dict)
    gt_names: list[str] = field(default_factory=list)
    pairs: int = 0

    @property
    def scored(self) -> int:
        """Number of scored voxels."""
        return self.tp + self.fp + self.fn + self.tn

    def __add__(self, other: "Counts") -> "Counts":
        classes = {k: v.copy() for k, v in self.classes.items()}
        for k, v in other.classes.items():
            classes[k] = classes[k] + v if k in classes else v.copy()
        names = list(self.gt_names) + [n for n in other.gt_names if n not in self.gt_names]
        return Counts(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn, self.tn + other.tn,
                      classes, names, self.pairs + other.pairs)


def _named_ids(grid: Grid) -> tuple[list[str], np.ndarray]:
    """Canonical class names of a grid and, per label id 0..255, the index of its name (-1: none)."""
    names: list[str] = []
    ids = np.full(256, -1, dtype=np.int64)
    for k, raw in enumerate(grid.class_names):
        if k == 0 or k >= 254:
            continue
        n = canonical_name(raw)
        if n in (EMPTY, UNLABELED, ""):
            continue
        if n not in names:
            names.append(n)
        ids[k] = names.index(n)
    return names, ids


def confusion(pred: Grid, gt: Grid) -> np.ndarray:
    """Raw (gt id, pred id) voxel counts on the ground-truth grid.

    Parameters
    ----------
    pred, gt : Grid
        Same voxel size (else :class:`PanovoccError`), any origins and extents.

    Returns
    -------
    C : (256, 256) int64
        ``C[g, p]`` = number of ground-truth voxels labelled ``g`` whose predicted label is ``p``;
        ground-truth voxels the prediction does not cover are counted with ``p = 255``. Row 255
        (unscored ground truth) is kept; callers drop it.
    """
    ov = overlap(gt, pred)
    gt_hist = np.bincount(gt.labels.reshape(-1), minlength=256).astype(np.int64)
    if ov.empty:
        C = np.zeros((256, 256), dtype=np.int64)
    else:
        g = gt.labels[ov.a_slices]
        p = pred.labels[ov.b_slices]
        key = (g.astype(np.uint16) << 8) | p  # uint16: half the memory of int32 keys
        C = np.bincount(key.reshape(-1), minlength=65536).astype(np.int64).reshape(256, 256)
    C[:, UNKNOWN] += gt_hist - C.sum(axis=1)  # uncovered ground truth -> predicted unknown
    return C


def counts_from_confusion(C: np.ndarray, pred: Grid, gt: Grid, mask: str) -> Counts:
    """Reduce a raw confusion matrix (:func:`confusion`) to occupancy and per-class counts."""
    if mask not in MASKS:
        raise ValueError(mask)
    C = C.copy()
    C[UNKNOWN, :] = 0  # ground truth 255 is never scored
    if mask == "observed":
        C[:, UNKNOWN] = 0  # nor what the prediction left unknown or does not cover
    occ = np.zeros(256, dtype=bool)
    occ[1:UNKNOWN] = True
    tp = int(C[np.ix_(occ, occ)].sum())
    fp = int(C[np.ix_(~occ, occ)].sum())
    fn = int(C[np.ix_(occ, ~occ)].sum())
    tn = int(C[np.ix_(~occ, ~occ)].sum())

    g_names, g_ids = _named_ids(gt)
    p_names, p_ids = _named_ids(pred)
    names = list(g_names) + [n for n in p_names if n not in g_names]
    U = len(names)
    Mg = np.zeros((256, U), dtype=np.int64)
    Mp = np.zeros((256, U), dtype=np.int64)
    for k in np.flatnonzero(g_ids >= 0):
        Mg[k, names.index(g_names[g_ids[k]])] = 1
    for k in np.flatnonzero(p_ids >= 0):
        Mp[k, names.index(p_names[p_ids[k]])] = 1
    both = Mg.T @ C @ Mp  # (U, U): gt name x pred name
    ctp = np.diag(both)
    gt_tot = Mg.T @ C.sum(axis=1)
    pred_tot = C.sum(axis=0) @ Mp
    classes = {n: np.array([ctp[i], pred_tot[i] - ctp[i], gt_tot[i] - ctp[i]], dtype=np.int64)
               for i, n in enumerate(names)}
    return Counts(tp, fp, fn, tn, classes, list(g_names), 1)


def count_pair(pred: Grid, gt: Grid) -> dict[str, Counts]:
    """Counts of one (prediction, ground truth) pair under both masks: ``{"freeocc": ..., "observed": ...}``."""
    C = confusion(pred, gt)
    return {m: counts_from_confusion(C, pred, gt, m) for m in MASKS}


def _ratio(tp: int, fp: int, fn: int) -> float:
    den = tp + fp + fn
    return 100.0 * tp / den if den > 0 else math.nan


def freeocc_class_iou(tp: int, fp: int, fn: int) -> float:
    """One class's IoU as FreeOcc's code computes it, percent: ``tp / (tp + fp + fn + 1e-5 + 1e-8)``.

    Never NaN: a class neither side has scores 0. Differs from the exact ratio by under 1e-5 / (tp + fp
    + fn) relative.
    """
    den = (float(tp) + float(fp) + float(fn) + FREEOCC_CLASS_EPS) + FREEOCC_SAFE_DIV_EPS
    return 100.0 * (float(tp) / den)


@dataclass
class Result:
    """Scores of one or several pooled pairs under one mask (all scores in percent).

    Attributes
    ----------
    counts : Counts
    mask : str, ``freeocc`` or ``observed``
    classes : list[str], the class set mIoU averages over (canonical names)
    info : dict, free-form provenance (pairs, paths, voxel size)
    """

    counts: Counts
    mask: str
    classes: list[str]
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def iou(self) -> float:
        """Occupancy IoU, percent (NaN when nothing is occupied on either side)."""
        c = self.counts
        return _ratio(c.tp, c.fp, c.fn)

    def class_iou(self, name: str) -> float:
        """IoU of one class (canonical name), percent; NaN when neither side has it."""
        v = self.counts.classes.get(canonical_name(name))
        return math.nan if v is None else _ratio(int(v[0]), int(v[1]), int(v[2]))

    def gt_voxels(self, name: str) -> int:
        """Scored ground-truth voxels of a class."""
        v = self.counts.classes.get(canonical_name(name))
        return 0 if v is None else int(v[0] + v[2])

    def class_iou_freeocc(self, name: str) -> float:
        """IoU of one class as FreeOcc's code computes it (:func:`freeocc_class_iou`), percent, never NaN."""
        v = self.counts.classes.get(canonical_name(name))
        return 0.0 if v is None else freeocc_class_iou(int(v[0]), int(v[1]), int(v[2]))

    @property
    def present(self) -> list[str]:
        """Classes of the set present in the ground truth (>= 1 scored voxel): those ``miou_present`` averages."""
        return [n for n in self.classes if self.gt_voxels(n) > 0]

    @property
    def absent(self) -> list[str]:
        """Classes of the set absent from the ground truth (they score 0 in the headline mIoU)."""
        return [n for n in self.classes if self.gt_voxels(n) == 0]

    @property
    def per_class(self) -> dict[str, float]:
        """Per-class IoU (percent, exact ratio) for every class of the set (NaN when neither side has it)."""
        return {n: self.class_iou(n) for n in self.classes}

    @property
    def per_class_freeocc(self) -> dict[str, float]:
        """Per-class IoU as FreeOcc's code computes it (percent; 0 for a class neither side has)."""
        return {n: self.class_iou_freeocc(n) for n in self.classes}

    @property
    def miou(self) -> float:
        """Headline mIoU, FreeOcc's rule: mean of :meth:`class_iou_freeocc` over **every** class of the set.

        A class absent from the ground truth counts with its FreeOcc IoU (0). NaN only for an empty set.
        """
        vals = [self.class_iou_freeocc(n) for n in self.classes]
        return float(np.mean(vals)) if vals else math.nan

    @property
    def miou_present(self) -> float:
        """Mean exact IoU over the classes of the set present in the ground truth (NaN if none is)."""
        vals = [self.class_iou(n) for n in self.present]
        return float(np.mean(vals)) if vals else math.nan

    @property
    def miou_rules_differ(self) -> bool:
        """True when a class of the set is absent from the ground truth, so the two mIoU rules differ."""
        return bool(self.absent)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN -> None)."""
        c = self.counts
        return {
            "mask": self.mask,
            "classes": list(self.classes),
            "present": self.present,
            "absent": self.absent,
            "iou": _nan_none(self.iou),
            "miou": _nan_none(self.miou),
            "miou_rule": "freeocc: mean over every class of the set, tp/(tp+fp+fn+1e-5), absent classes 0",
            "miou_present": _nan_none(self.miou_present),
            "per_class": {n: _nan_none(v) for n, v in self.per_class.items()},
            "per_class_freeocc": dict(self.per_class_freeocc),
            "counts": {"tp": c.tp, "fp": c.fp, "fn": c.fn, "tn": c.tn, "scored": c.scored, "pairs": c.pairs},
            "class_counts": {n: {"tp": int(v[0]), "fp": int(v[1]), "fn": int(v[2])} for n, v in c.classes.items()},
            "info": dict(self.info),
        }

    def to_dataframe(self, name: str | None = None):
        """One-row pandas DataFrame: ``IoU``, ``mIoU`` (FreeOcc), ``mIoU_present``, then one column per class.

        The row is indexed by ``name`` (default: the mask), so results concatenate into a table.
        """
        import pandas as pd

        row = {"mask": self.mask, "IoU": self.iou, "mIoU": self.miou, "mIoU_present": self.miou_present}
        row.update(self.per_class)
        return pd.DataFrame([row], index=[name if name is not None else self.mask])


def _nan_none(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)


def resolve_classes(spec: str, counts: Counts) -> list[str]:
    """The class set of a ``--classes`` spec (eval8 | open4 | eval12 | all | a,b,c); ``all`` = the ground truth's names."""
    return parse_class_set(spec, counts.gt_names)


def evaluate(pairs: Iterable[tuple[Grid, Grid]], classes: str = "eval8",
             info: dict[str, Any] | None = None) -> dict[str, Result]:
    """Score and pool (prediction, ground truth) pairs.

    Parameters
    ----------
    pairs : iterable of (pred Grid, gt Grid)
    classes : str, class set spec (eval8 | open4 | eval12 | all | comma list)
    info : dict, provenance stored in each Result

    Returns
    -------
    dict mask -> Result, for both masks (``freeocc`` is the headline)
    """
    total = {m: Counts() for m in MASKS}
    for pred, gt in pairs:
        c = count_pair(pred, gt)
        for m in MASKS:
            total[m] = total[m] + c[m]
    names = resolve_classes(classes, total[HEADLINE_MASK])
    return {m: Result(total[m], m, names, dict(info or {})) for m in MASKS}
