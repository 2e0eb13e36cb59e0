"""2D (per-frame, per-pixel) segmentation quality of a segmenter against ground-truth labels.

Scored pixels are the labelled ones (ground-truth id != 0). For a class ``k`` of the chosen set,
matched by canonical name: TP = predicted k and ground truth k; FP = predicted k, ground truth another
labelled class (also one outside the set, e.g. a rug predicted ``floor``); FN = ground truth k,
predicted something else. Counts are pooled over frames before dividing; mIoU is the mean IoU over
the classes of the set present in the ground truth (the FreeOcc rule, applied to pixels). A class of
the set that is missing from the vocabulary is never predicted, so its IoU is 0 where present.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..classes import EVAL8, canonical_name
from ..errors import PanovoccError


@dataclass
class Miou2D:
    """Pooled 2D segmentation scores.

    Attributes
    ----------
    classes : list of str, the scored class set
    tp, fp, fn : (len(classes),) int64 pooled pixel counts
    correct, scored : int, pixels whose predicted name equals the ground-truth name / labelled pixels
    frames : int, frames scored
    """

    classes: list[str]
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    correct: int = 0
    scored: int = 0
    frames: int = 0
    present: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def iou(self) -> dict[str, float]:
        """Per-class IoU (NaN for classes absent from the ground truth and never predicted)."""
        den = self.tp + self.fp + self.fn
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(den > 0, self.tp / np.maximum(den, 1), np.nan)
        return {c: float(x) for c, x in zip(self.classes, v)}

    @property
    def miou(self) -> float:
        """Mean IoU over the classes present in the ground truth (NaN if none is)."""
        if not self.present.any():
            return float("nan")
        den = (self.tp + self.fp + self.fn)[self.present]
        return float(np.mean(self.tp[self.present] / den))

    @property
    def accuracy(self) -> float:
        """Fraction of labelled pixels whose predicted name is the ground-truth name."""
        return self.correct / self.scored if self.scored else float("nan")

    def add(self, other: "Miou2D") -> None:
        """Pool another result over the same class set into this one."""
        self.tp += other.tp
        self.fp += other.fp
        self.fn += other.fn
        self.correct += other.correct
        self.scored += other.scored
        self.frames += other.frames
        self.present |= other.present


def frame_scores(pred: np.ndarray, vocab: Sequence[str], labels: np.ndarray, class_names: Sequence[str],
                 classes: Sequence[str] = EVAL8) -> Miou2D:
    """Scores of one frame.

    Parameters
    ----------
    pred : (H, W) int, predicted vocabulary indices
    vocab : sequence of str, the C vocabulary names ``pred`` indexes
    labels : (H, W) int, ground-truth ids into ``class_names`` (0 = unlabeled, not scored)
    class_names : sequence of str, the sequence's class names
    classes : sequence of str, the scored class set (default eval8)
    """
    pred = np.asarray(pred, dtype=np.int64)
    labels = np.asarray(labels, dtype=np.int64)
    if pred.shape != labels.shape:
        raise PanovoccError(f"prediction {pred.shape} and labels {labels.shape} differ in shape")
    classes = [canonical_name(c) for c in classes]
    names: dict[str, int] = {}
    for n in [canonical_name(v) for v in vocab] + [canonical_name(n) for n in class_names[1:]]:
        names.setdefault(n, len(names))
    vocab_ids = np.array([names[canonical_name(v)] for v in vocab], dtype=np.int64)
    gt_ids = np.array([-1] + [names[canonical_name(n)] for n in class_names[1:]], dtype=np.int64)
    m = labels > 0
    p = vocab_ids[pred[m]]
    g = gt_ids[labels[m]]
    cls = np.array([names.get(c, -2) for c in classes], dtype=np.int64)
    tp = np.array([np.count_nonzero((p == k) & (g == k)) for k in cls], dtype=np.int64)
    pc = np.array([np.count_nonzero(p == k) for k in cls], dtype=np.int64)
    gc = np.array([np.count_nonzero(g == k) for k in cls], dtype=np.int64)
    return Miou2D(classes=list(classes), tp=tp, fp=pc - tp, fn=gc - tp, correct=int(np.count_nonzero(p == g)),
                  scored=int(m.sum()), frames=1, present=gc > 0)


def empty_scores(classes: Sequence[str]) -> Miou2D:
    """Zero scores over a class set, to pool frames into with :meth:`Miou2D.add`."""
    n = len(classes)
    return Miou2D(classes=[canonical_name(c) for c in classes], tp=np.zeros(n, np.int64), fp=np.zeros(n, np.int64),
                  fn=np.zeros(n, np.int64), present=np.zeros(n, dtype=bool))
