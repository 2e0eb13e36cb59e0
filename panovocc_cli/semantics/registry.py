"""Segmenters by name: the one place that knows every segmenter module (no module imports another).

Specs (``--segmenter``):

* ``simulated`` or ``simulated:MODEL``: the ground-truth simulator (:mod:`.simulated`) with confidence
  model ``MODEL`` (``calibrated``, the default, ``overconfident`` or ``raw``; see
  :data:`.simulated.CONFIDENCE_MODELS`). It reads labels through the ``label_source`` it is built with.
* ``precomputed:DIR``: per-frame scores another model wrote (:mod:`.precomputed`).
* ``clip`` or ``clip:MODEL@WEIGHTS[,options]`` / ``clip:FOLDER[,options]``: the training-free dense CLIP
  segmenter (NACLIP's recipe) on tiles of the panorama (:mod:`.clip`; optional extra ``.[clip]``).

Two more specs name no segmenter: ``none`` (:data:`SEGMENTER_NONE`, a geometry-only map) and ``auto``
(:data:`SEGMENTER_AUTO`, the map command's default: ``simulated`` where the sequence has labels).
"""

from __future__ import annotations

import numpy as np

from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from .segmenter import Segmenter

SIMULATED = "simulated"
PRECOMPUTED = "precomputed:"
CLIP = "clip"
SEGMENTER_NONE = "none"
SEGMENTER_AUTO = "auto"


def build_segmenter(spec: str = SIMULATED, *, seed: int = DEFAULT_SEED, noise: float = 1.0,
                    label_source=None) -> Segmenter:
    """Build a segmenter from its command-line spec.

    Parameters
    ----------
    spec : str
        ``simulated[:MODEL]``, ``precomputed:DIR`` or ``clip[...]`` (see the module docstring).
    seed : int
        Seed of the simulated segmenter's noise (frame ``i`` uses ``default_rng([seed, i])``).
    noise : float
        Noise level of the simulated segmenter; 1.0 is the documented default, 0 makes it exact.
    label_source : callable ``frame_id -> (labels (H, W) int, class_names)`` or None
        The simulator's ground truth (e.g. :func:`.simulated.sequence_label_source`); ignored by the
        other segmenters. Without it a simulated segmenter is built (specs validate) but cannot run.

    Raises
    ------
    PanovoccError
        For an unknown spec or confidence model, a negative noise level, a precomputed folder that
        fails validation, or a clip spec whose weights are not on disk (one line saying how to provide them).
    """
    s = spec.strip()
    if s == SIMULATED or s.startswith(SIMULATED + ":"):
        from .simulated import CONFIDENCE_MODELS, SimulatedConfig, SimulatedSegmenter

        model = s[len(SIMULATED) + 1:] if ":" in s else "calibrated"
        if model not in CONFIDENCE_MODELS:
            raise PanovoccError(f"unknown confidence model {model!r} in segmenter {spec!r}: expected "
                                f"{', '.join(SIMULATED + ':' + m for m in CONFIDENCE_MODELS)}")
        if not np.isfinite(noise) or noise < 0:
            raise PanovoccError(f"segmenter noise must be a finite number >= 0, got {noise}")
        return SimulatedSegmenter(label_source, SimulatedConfig(noise=float(noise), seed=int(seed), confidence=model))
    if s.startswith(PRECOMPUTED):
        from .precomputed import PrecomputedSegmenter

        folder = s[len(PRECOMPUTED):]
        if not folder:
            raise PanovoccError("segmenter 'precomputed:' needs a folder, e.g. precomputed:runs/seg")
        return PrecomputedSegmenter(folder)
    if s == CLIP or s.startswith(CLIP + ":") or s.startswith(CLIP + ","):
        from .clip import ClipSegmenter

        return ClipSegmenter(s)
    raise PanovoccError(f"unknown segmenter {spec!r}: expected 'simulated', 'simulated:overconfident', "
                        "'precomputed:DIR' or 'clip[:MODEL@WEIGHTS]'")


def is_simulated(spec: str) -> bool:
    """Whether ``spec`` names the ground-truth simulator (which needs a sequence with labels)."""
    s = spec.strip()
    return s == SIMULATED or s.startswith(SIMULATED + ":")
