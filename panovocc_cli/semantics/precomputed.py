"""``precomputed:DIR``: a segmenter that reads per-frame class scores another model wrote.

The file format (``vocab.json``, ``<stem>.npz`` logits/probs, ``<stem>.png`` labels with an optional
``<stem>_conf.png``) is :mod:`panovocc_cli.io.precomputed` (documented in docs/semantics.md). Here the
stored scores are turned into log-probabilities over the file's vocabulary, then mapped onto the user's
vocabulary by canonical name; a user word the file lacks gets :data:`MISSING_LOGPROB` (about 1e-6).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..classes import canonical_name
from ..errors import PanovoccError
from ..io.precomputed import (DEFAULT_LABEL_CONFIDENCE, FrameScores, read_frame_scores, read_vocab_json,  # noqa: F401
                              write_precomputed, write_precomputed_labels)
from ..io.sequence import frame_stem
from .segmenter import Segmenter

MISSING_LOGPROB = float(np.log(1e-6))


def log_softmax(x: np.ndarray) -> np.ndarray:
    """Stable log-softmax over the last axis, float32."""
    x = np.asarray(x, dtype=np.float32)
    m = x.max(axis=-1, keepdims=True)
    z = x - m
    return z - np.log(np.exp(z).sum(axis=-1, keepdims=True))


def load_frame_scores(folder: str | Path, stem: str, n_classes: int, shape: tuple[int, int] | None) -> np.ndarray:
    """Log-probabilities ``(H, W, n_classes)`` float32 of one frame over the file vocabulary (validated)."""
    s: FrameScores = read_frame_scores(folder, stem, n_classes, shape)
    if s.kind == "logits":
        return log_softmax(s.array)
    if s.kind == "probs":
        return np.log(np.clip(s.array, 1e-6, 1.0)).astype(np.float32)
    return labels_to_logprobs(s.array, s.confidence, n_classes, s.none_id)


def labels_to_logprobs(labels: np.ndarray, confidence: np.ndarray, n_classes: int, none_id: int = -1) -> np.ndarray:
    """Log-probabilities ``(H, W, n)`` float32 of hard labels with a confidence each.

    The labelled class gets ``max(confidence, 1/n)``, the others share the rest equally; pixels whose id
    is ``none_id`` get a flat distribution.
    """
    n = n_classes
    c = np.clip(np.asarray(confidence, dtype=np.float32), 1.0 / n, 1.0 - 1e-6) if n > 1 else np.ones_like(
        confidence, dtype=np.float32)
    rest = (1.0 - c) / max(n - 1, 1)
    p = np.broadcast_to(rest[..., None], labels.shape + (n,)).copy()
    ok = labels != none_id
    rows, cols = np.nonzero(ok)
    p[rows, cols, labels[rows, cols]] = c[rows, cols]
    p[~ok] = 1.0 / n
    return np.log(np.clip(p, 1e-6, 1.0)).astype(np.float32)


def map_to_vocab(logprobs: np.ndarray, file_vocab: Sequence[str], vocab: Sequence[str]) -> np.ndarray:
    """Re-index file-vocabulary log-probabilities ``(H, W, F)`` onto the user's vocabulary ``(H, W, C)``.

    Words are matched by canonical name; a user word missing from the file gets :data:`MISSING_LOGPROB`.
    """
    pos = {canonical_name(n): i for i, n in enumerate(file_vocab)}
    out = np.full(logprobs.shape[:2] + (len(vocab),), MISSING_LOGPROB, dtype=np.float32)
    for j, v in enumerate(vocab):
        i = pos.get(canonical_name(v))
        if i is not None:
            out[..., j] = np.maximum(logprobs[..., i], MISSING_LOGPROB)
    return out


class PrecomputedSegmenter(Segmenter):
    """Reads ``DIR/<stem>.npz`` or ``DIR/<stem>.png`` per frame (see the module docstring)."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.file_vocab = read_vocab_json(self.folder)
        self.spec = f"precomputed:{folder}"

    def logits(self, rgb: np.ndarray, vocab: Sequence[str], *, frame_id=None) -> np.ndarray:
        """Log-probabilities ``(H, W, C)`` float32 over ``vocab`` (valid logits; see :class:`Segmenter`).

        ``frame_id``: the frame's index in its sequence (int, file ``DIR/<frame_stem(i)>.*``) or a file
        stem (str)."""
        if frame_id is None:
            raise PanovoccError("a precomputed segmenter needs the frame id (which file to read)", self.folder)
        known = {canonical_name(n) for n in self.file_vocab}
        if not any(canonical_name(v) in known for v in vocab):
            raise PanovoccError(f"none of the vocabulary words {list(vocab)} appear in vocab.json "
                                f"{self.file_vocab}", self.folder / "vocab.json")
        shape = None if rgb is None else tuple(np.shape(rgb)[:2])
        stem = frame_id if isinstance(frame_id, str) else frame_stem(int(frame_id))
        lp = load_frame_scores(self.folder, stem, len(self.file_vocab), shape)
        return map_to_vocab(lp, self.file_vocab, vocab)
