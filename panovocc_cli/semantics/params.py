"""Parameter dataclasses of the semantics layer, in a module that imports nothing heavy.

The stage configs (``mapping/config.py``) hold these, and ``panovocc --help`` builds the command line
from those configs, so this module must import only the standard library (no numba: ``--help`` stays
instant). :mod:`panovocc_cli.semantics.evidence` re-exports :class:`EvidenceWeights`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EvidenceWeights:
    """Parameters of eta = c * w_erp(phi) * w_range(r) (see the module docstring)."""

    erp_power: float = 1.0
    erp_floor: float = 0.05
    range_scale: float = 4.0  # metres
