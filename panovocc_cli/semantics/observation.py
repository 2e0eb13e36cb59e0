"""A frame's semantic observation: what the mapper keeps of a segmenter's output.

The segmenter's logits ``(h, w, C)`` at the semantic stride are reduced, once, to the observation the map
fuses and keeps: per measurement pixel its two most probable classes and their softmax probabilities in
steps of 1/15 (four bits each). The semantic evidence of a frame is computed from this observation, never
from the logits, so the observation is all a revision needs: revising a frame under a new pose reads its
depth and colours again, takes the observation kept with its delta, and never calls the segmenter
(docs/semantics.md, "Semantic observation"). At 1024x512 (semantic stride 2) it is about 37 kB a frame.

Per pixel, from ``p = softmax(logits)``:

* ``classes`` : ``(c1, c2)``, the indices of the largest and second-largest probability (ties: the lower
  index first);
* ``q`` : ``(round(15 p_c1), round(15 p_c2))``, uint8 in 0..15.

What the evidence uses (:func:`.evidence._pixel_measurement`, per pixel where the sums read it): the confidence ``q1 / 15`` (the paper's ``c``, the maximum
class probability) and the distribution ``(q1, q2) / (q1 + q2)`` on ``(c1, c2)`` (zero elsewhere). The
third and later classes hold 11 % of the probability mass on average with the simulated segmenter at
1024x512 (top-1 72 %, top-2 84 %); dropping them changes a voxel's fused distribution little, because a
frame's evidence is averaged over the voxel's pixels and the frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import PanovoccError

Q_LEVELS = 15  # probabilities in steps of 1 / Q_LEVELS (four bits)
MAX_CLASSES = 255  # class indices are uint8


@dataclass(frozen=True)
class SemanticObservation:
    """A frame's kept segmenter output at the semantic stride.

    Attributes
    ----------
    classes : (h, w, 2) uint8, the two most probable vocabulary indices of each measurement pixel
    q : (h, w, 2) uint8 in 0..15, their probabilities in 1/15
    n_classes : int, the vocabulary size C the indices refer to
    features : (h, w, D) int8 or None, the segmenter's per-pixel embeddings projected to the map's D
        dimensions and quantised to unit vectors in 1/127 steps (:func:`.features.quantize_features`); None
        for a map without a feature channel
    """

    classes: np.ndarray
    q: np.ndarray
    n_classes: int
    features: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w): the measurement grid."""
        return tuple(self.classes.shape[:2])

    def check(self, where=None) -> "SemanticObservation":
        """Validate shapes, dtypes and ranges; raise :class:`PanovoccError` naming what is wrong."""
        c, q = np.asarray(self.classes), np.asarray(self.q)
        if c.ndim != 3 or c.shape[2] != 2 or q.shape != c.shape or c.dtype != np.uint8 or q.dtype != np.uint8:
            raise PanovoccError(f"semantic observation: classes {c.dtype} {c.shape} and q {q.dtype} {q.shape}, "
                                "expected uint8 (h, w, 2) both", where)
        if not 1 <= int(self.n_classes) <= MAX_CLASSES or (c.size and int(c.max()) >= self.n_classes) \
                or (q.size and int(q.max()) > Q_LEVELS):
            raise PanovoccError(f"semantic observation: class indices must be < {self.n_classes} and q <= {Q_LEVELS}",
                                where)
        if self.features is not None:
            f = np.asarray(self.features)
            if f.dtype != np.int8 or f.ndim != 3 or f.shape[:2] != c.shape[:2] or f.shape[2] < 1:
                raise PanovoccError(f"semantic observation: features {f.dtype} {f.shape}, expected int8 "
                                    f"{c.shape[:2] + ('D',)}", where)
        return self

    def to_arrays(self) -> dict:
        """The arrays a delta record keeps: ``q`` as one byte a pixel (``q1 << 4 | q2``), ``classes`` the
        same way when the vocabulary has at most 16 words (``packed`` = 1), else as they are; and
        ``n_classes``; ``features`` (int8) when the observation has them. Packed, the two planes compress to
        about three quarters of their bytes unpacked."""
        q = np.asarray(self.q, np.uint8)
        c = np.asarray(self.classes, np.uint8)
        packed = self.n_classes <= 16
        out = {"q": (q[..., 0] << 4) | q[..., 1],
               "classes": ((c[..., 0] << 4) | c[..., 1]) if packed else np.ascontiguousarray(c),
               "packed": np.array([int(packed)], np.int64), "n_classes": np.array([int(self.n_classes)], np.int64)}
        if self.features is not None:
            out["features"] = np.ascontiguousarray(self.features, np.int8)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict, where=None) -> "SemanticObservation":
        """Inverse of :meth:`to_arrays` (validated)."""
        try:
            q = np.asarray(arrays["q"], np.uint8)
            c = np.asarray(arrays["classes"], np.uint8)
            q = np.stack([q >> 4, q & 15], axis=-1)
            if int(np.asarray(arrays["packed"]).reshape(-1)[0]):
                c = np.stack([c >> 4, c & 15], axis=-1)
            f = np.asarray(arrays["features"]) if "features" in arrays else None
            if f is not None and f.dtype != np.int8:
                raise ValueError(f"features are {f.dtype}, expected int8")
            obs = cls(c, q, int(np.asarray(arrays["n_classes"]).reshape(-1)[0]), f)
        except (KeyError, IndexError, ValueError, TypeError) as e:
            raise PanovoccError(f"semantic observation unreadable ({type(e).__name__}: {e})", where) from None
        return obs.check(where)


def observe(logits: np.ndarray) -> SemanticObservation:
    """The observation of segmenter logits ``(h, w, C)`` (float; C >= 1): top-2 classes and their softmax
    probabilities in 1/15 steps (a compiled pass over the pixels, rows in parallel; a pixel's result never
    depends on the others, so it is deterministic)."""
    lg = np.asarray(logits)
    if lg.ndim != 3 or lg.shape[2] < 1:
        raise PanovoccError(f"logits must be (h, w, C), got shape {lg.shape}")
    C = lg.shape[2]
    if C > MAX_CLASSES:
        raise PanovoccError(f"a vocabulary of {C} words is more than the {MAX_CLASSES} a semantic observation holds")
    lg = np.ascontiguousarray(lg, dtype=np.float32)
    if not np.isfinite(lg).all():
        raise PanovoccError("segmenter logits must be finite")
    classes = np.empty(lg.shape[:2] + (2,), np.uint8)
    q = np.empty(lg.shape[:2] + (2,), np.uint8)
    _observe(lg, classes, q, np.float64(Q_LEVELS))
    return SemanticObservation(classes, q, C)


@nb.njit(cache=True, parallel=True)
def _observe(logits, classes, q, levels):
    """Per pixel: the two largest logits' classes (ties: the lower index first) and their softmax
    probabilities ``exp(l - max) / sum exp(l - max)`` (float64) times ``levels``, rounded half to even."""
    h, w, C = logits.shape
    for v in nb.prange(h):
        for u in range(w):
            l = logits[v, u]
            i1 = 0
            for k in range(1, C):
                if l[k] > l[i1]:
                    i1 = k
            i2 = -1
            for k in range(C):
                if k != i1 and (i2 < 0 or l[k] > l[i2]):
                    i2 = k
            m = np.float64(l[i1])
            tot = 0.0
            e2 = 0.0
            for k in range(C):
                if k == i1:  # exp(0) is 1 exactly: the same sum, one exponential less
                    tot += 1.0
                else:
                    e = np.exp(np.float64(l[k]) - m)
                    tot += e
                    if k == i2:  # kept for q2: the same value, not computed twice
                        e2 = e
            classes[v, u, 0] = i1
            q[v, u, 0] = np.uint8(np.rint(levels / tot))
            if i2 < 0:  # one class
                classes[v, u, 1] = 0
                q[v, u, 1] = 0
            else:
                classes[v, u, 1] = i2
                q[v, u, 1] = np.uint8(np.rint(levels * e2 / tot))

