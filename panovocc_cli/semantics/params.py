"""Parameter dataclasses of the semantics layer, in a module that imports nothing heavy.

The stage configs (``mapping/config.py``) hold these, and ``panovocc --help`` builds the command line
from those configs, so this module must import only the standard library (no numba: ``--help`` stays
instant). :mod:`panovocc_cli.semantics.evidence` re-exports :class:`EvidenceWeights`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EvidenceWeights:
    """Parameters of eta = c * w_erp(phi) * w_range(r) (see the module docstring), and which pixels are
    measurements: every ``stride``-th pixel along both axes (rows and columns 0, s, 2s, ...), each then
    weighing ``stride ** 2`` (it stands for an s x s block of pixels, so E and S keep their scale and the
    GSC anchor its meaning). 1 = every pixel; the map command resolves its ``--semantic-stride``
    (default ``max(1, W // 512)``) into this field, and a saved config without it predates it (1)."""

    erp_power: float = 1.0
    erp_floor: float = 0.05
    range_scale: float = 4.0  # metres
    stride: int = 1  # pixels
