"""The mapper's geometric parameters, in a module light enough for the CLI to read its defaults.

Defaults and the reasons for them: docs/mapping.md ("Defaults and why", "Quality").
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class GeometryParams:
    """Parameters of the geometry contributor (defaults and reasons: docs/mapping.md)."""

    voxel_size: float = 0.08  # metres
    stride: int = 4  # pixels between samples of the kernel lift
    kernel: str = "psvf"  # "psvf" or "point"
    alpha: float = 0.0025  # radial kernel scale: alpha * r + beta (dimensionless)
    beta: float = 0.0025  # metres
    kappa: float = 1.5  # Mahalanobis truncation radius (of the tangential Gaussian for box / surfel)
    w_pole: float = 0.5  # latitude weight at the poles (1 at the equator)
    r_half: float = 8.0  # metres; range weight 1 / (1 + r / r_half)
    eps_abs: float = 0.07  # metres; free-space margin eps(r) = eps_abs + eps_rel r
    eps_rel: float = 0.01
    stable_k: float = 2.0  # neighbour depths within stable_k * eps(r) count as stable
    min_range: float = 0.1  # metres; depths and voxels nearer than this are ignored
    max_range: float = 12.0  # metres; depths and voxels farther than this are ignored
    extent: str = "surfel"  # "surfel": kernel on the local surface plane, factor P(plane through the voxel box);
    # "box": radial factor = P(ray coordinate in the voxel's chord); "centre": the paper's
    n_min: float = 0.2  # a frame counts in N only when its support dA exceeds this (paper: 0)
    carve_extent: bool = True  # carve only voxels whose whole box lies in front of the observed local plane
    drop_below_n_min: bool = False  # a frame's support dA <= n_min is dropped from A as well as from N
    n_floor: float = 0.003  # metres; surfel kernel: floor of the scale along the normal
    c_min: float = 0.25  # surfel kernel: |cos incidence| floor of the in-plane footprint stretch
    surfel_fit: bool = True  # surfel kernel: centre on the plane fitted to the sample and its 4 neighbours
    edge_abs: float = 0.0  # metres; surfel kernel: edge tolerance = disc_k (alpha r + beta) + edge_abs
    disc_k: float = 3.0  # surfel kernel: edge/corner if a sample is farther than disc_k (alpha r + beta) + edge_abs
    # from the line through its two neighbours (per image axis)


@dataclass(frozen=True)
class OccupancyParams:
    """Decision thresholds (defaults and reasons: docs/mapping.md)."""

    lambda_f: float = 1.0  # weight of the free-space ratio in g
    tau_s: float = 0.12  # strong support: accepted whatever the free-space ratio
    tau_w: float = 0.04  # weak support: accepted only if F / max(O, 1) <= gamma_f
    gamma_f: float = 0.6  # largest admissible free-space ratio for weak support
