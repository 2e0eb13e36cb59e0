"""The segmenter interface: an ERP RGB frame and a vocabulary in, per-pixel logits ``(H, W, C)`` out.

The generic call carries no ground truth: ``Segmenter.logits(rgb, vocab, *, frame_id=None)``. The
``frame_id`` is an opaque key for segmenters whose output is stored or simulated per frame (a
precomputed folder picks its file by it, the simulator its labels and noise seed); a network would
ignore it. Segmenters are built by name in :mod:`.registry` (``build_segmenter``):

* ``simulated`` (the default; ``simulated:overconfident`` etc. choose its confidence model): a
  simulator built with its label source (:mod:`.simulated`);
* ``precomputed:DIR``: per-frame scores another model wrote (:mod:`.precomputed`).

The vocabulary parser is :func:`panovocc_cli.classes.parse_vocab`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Sequence

import numpy as np


class Segmenter(ABC):
    """Per-pixel class scores over a run-time vocabulary.

    Subclasses implement :meth:`logits`; :attr:`spec` is the string that rebuilds the segmenter through
    :func:`.registry.build_segmenter` (saved in a run's config).
    """

    spec: str = ""

    def prepare(self) -> None:
        """Load now what the first frame would (a network's weights, its device), so that a segmenter
        that cannot run fails (:class:`PanovoccError`) before a command writes anything. Default: nothing
        to load."""

    @abstractmethod
    def logits(self, rgb: np.ndarray, vocab: Sequence[str], *, frame_id=None) -> np.ndarray:
        """Per-pixel logits of one ERP frame.

        Parameters
        ----------
        rgb : (H, W, 3) uint8, the frame's colours
        vocab : list of str, canonical class names (:func:`classes.parse_vocab`), C of them
        frame_id : hashable or None, opaque key of the frame for per-frame sources (its index in a
            sequence for ``simulated`` and ``precomputed:DIR``); never ground truth

        Returns
        -------
        logits : (H, W, C) float32, finite; ``softmax`` over the last axis gives class probabilities
        """

    def features(self, rgb: np.ndarray, *, frame_id=None) -> np.ndarray:
        """Per-pixel language-aligned embeddings of one ERP frame, ``(H, W, F)`` float32 (F: the segmenter's
        embedding dimension; text embedded by :meth:`text_encoder` lives in the same space). What a map made
        with ``--features`` fuses (:mod:`.features`). Default: this segmenter gives none."""
        from ..errors import PanovoccError

        raise PanovoccError(f"segmenter {self.spec or type(self).__name__!r} gives no per-pixel embeddings: --features "
                            "needs --segmenter simulated or clip")

    def text_encoder(self):
        """The :data:`.query.TextEncoder` whose embeddings live in the space of :meth:`features` (a map's
        feature queries embed their text with it). Default: none."""
        from ..errors import PanovoccError

        raise PanovoccError(f"segmenter {self.spec or type(self).__name__!r} has no text encoder for feature queries")

