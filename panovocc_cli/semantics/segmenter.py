"""The segmenter interface: an ERP RGB frame and a vocabulary in, per-pixel logits ``(H, W, C)`` out.

Two segmenters ship with the toolkit:

* ``simulated`` (the default): built from the sequence's ground-truth labels, it behaves like a real
  open-vocabulary segmenter on indoor panoramas (see :mod:`panovocc_cli.semantics.simulated`);
* ``precomputed:DIR``: per-frame scores another model wrote (see :mod:`panovocc_cli.semantics.precomputed`).

:func:`make_segmenter` builds one from its command-line spec; :func:`parse_vocab` turns ``--vocab``
into a list of class names.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from ..classes import DEFAULT_VOCAB, EMPTY, EVAL8, OPEN4, UNLABELED, canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError

# Grid labels 1..253 index a class list whose entry 0 is "empty" (CONVENTIONS.md).
MAX_VOCAB = 253

_NAMED_SETS: dict[str, tuple[str, ...]] = {
    "eval8": EVAL8,
    "open4": OPEN4,
    "eval12": DEFAULT_VOCAB,
    "default": DEFAULT_VOCAB,
}


def parse_vocab(spec: str | Sequence[str] | None = None) -> list[str]:
    """Resolve a ``--vocab`` value into a list of canonical class names.

    Parameters
    ----------
    spec : str, sequence of str or None
        ``None`` or ``"default"`` gives eval8 + open4 (:data:`classes.DEFAULT_VOCAB`). A string is a
        comma- or ``+``-separated list whose items are class names or the named sets ``eval8``,
        ``open4``, ``eval12`` (e.g. ``"eval8+open4"``, ``"eval8,pillow,rug"``, ``"chair,sofa"``).

    Returns
    -------
    vocab : list of str
        Lower-case canonical names (:func:`classes.canonical_name`: ``lamp`` -> ``lighting``), in the
        order given, duplicates removed (first occurrence kept).

    Raises
    ------
    PanovoccError
        If the vocabulary is empty, names the reserved ``empty``/``unlabeled`` classes, or has more
        than 253 classes (the grid format's limit).
    """
    if spec is None:
        items: Iterable[str] = DEFAULT_VOCAB
        shown = "default"
    elif isinstance(spec, str):
        shown = spec
        items = [t for part in spec.split(",") for t in part.split("+")]
    else:
        shown = ",".join(map(str, spec))
        items = spec
    out: list[str] = []
    seen: set[str] = set()
    for raw in items:
        if not isinstance(raw, str):
            raise PanovoccError(f"vocabulary {shown!r}: class names must be strings, got {raw!r}")
        token = raw.strip().lower()
        if not token:
            continue
        names = _NAMED_SETS.get(token, (token,))
        for n in names:
            c = canonical_name(n)
            if c in (EMPTY, UNLABELED):
                raise PanovoccError(f"vocabulary {shown!r}: {c!r} is reserved (id 0 of images and grids)")
            if c not in seen:
                seen.add(c)
                out.append(c)
    if not out:
        raise PanovoccError(
            f"empty vocabulary {shown!r}: expected class names or eval8/open4/eval12, e.g. 'eval8,curtain'"
        )
    if len(out) > MAX_VOCAB:
        raise PanovoccError(f"vocabulary has {len(out)} classes, at most {MAX_VOCAB} fit in a grid")
    return out


@dataclass(frozen=True)
class FrameContext:
    """What a simulated segmenter needs to know about a frame; real models ignore it.

    Attributes
    ----------
    labels : (H, W) int64 or None
        Ground-truth class ids into ``class_names`` (0 = unlabeled), or None when the sequence has none.
    class_names : sequence of str
        The sequence's ``meta.json`` class names (entry 0 is ``unlabeled``).
    """

    labels: np.ndarray | None
    class_names: Sequence[str]


class Segmenter(ABC):
    """Per-pixel class scores over a run-time vocabulary.

    Subclasses implement :meth:`logits`; :attr:`spec` is the string that rebuilds the segmenter through
    :func:`make_segmenter` (saved in a run's config).
    """

    spec: str = ""

    @abstractmethod
    def logits(self, rgb: np.ndarray, vocab: Sequence[str], frame_index: int,
               context: FrameContext | None = None) -> np.ndarray:
        """Per-pixel logits of one ERP frame.

        Parameters
        ----------
        rgb : (H, W, 3) uint8, the frame's colours
        vocab : list of str, canonical class names (:func:`parse_vocab`), C of them
        frame_index : int, position of the frame in its sequence (selects files, seeds noise)
        context : FrameContext or None, ground truth for simulated segmenters

        Returns
        -------
        logits : (H, W, C) float32, finite; ``softmax`` over the last axis gives class probabilities
        """


def make_segmenter(spec: str = "simulated", *, seed: int = DEFAULT_SEED, noise: float = 1.0) -> Segmenter:
    """Build a segmenter from its command-line spec.

    Parameters
    ----------
    spec : str
        ``simulated`` (ground-truth based, seeded) or ``precomputed:DIR`` (scores written by another model).
    seed : int
        Seed of the simulated segmenter's noise (frame ``i`` uses ``(seed, i)``).
    noise : float
        Noise level of the simulated segmenter; 1.0 is the documented default, 0 makes it exact.

    Raises
    ------
    PanovoccError
        For an unknown spec, a negative noise level, or a precomputed folder that fails validation.
    """
    s = spec.strip()
    if s == "simulated":
        from .simulated import SimulatedSegmenter, SimulatedConfig

        if not np.isfinite(noise) or noise < 0:
            raise PanovoccError(f"segmenter noise must be a finite number >= 0, got {noise}")
        return SimulatedSegmenter(SimulatedConfig(noise=float(noise), seed=int(seed)))
    if s.startswith("precomputed:"):
        from .precomputed import PrecomputedSegmenter

        folder = s[len("precomputed:"):]
        if not folder:
            raise PanovoccError("segmenter 'precomputed:' needs a folder, e.g. precomputed:runs/seg")
        return PrecomputedSegmenter(folder)
    raise PanovoccError(f"unknown segmenter {spec!r}: expected 'simulated' or 'precomputed:DIR'")
