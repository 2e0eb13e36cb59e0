"""The mapper's geometric parameters, in a module light enough for the CLI to read its defaults.

Defaults and the reasons for them: docs/mapping.md ("Defaults and why", "Quality").
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import DEFAULT_VOXEL_SIZE


@dataclass(frozen=True)
class GeometryParams:
    """Parameters of the geometry contributor (defaults and reasons: docs/mapping.md)."""

    voxel_size: float = DEFAULT_VOXEL_SIZE  # metres
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
    n_fill: float = 0.4  # a frame counts in N where a measurement lies in the voxel or its support dA >= n_fill
    hit_k: float = 1.0  # surfel kernel: a measurement also counts in N for the voxels of x +- hit_k s n where
    hit_max: float = 0.0005  # metres; ... s (the fitted position's std along n) <= hit_max: planes on a voxel face
    carve_extent: bool = True  # carve only voxels whose whole box lies in front of the observed local plane
    n_floor: float = 0.001  # metres; surfel kernel: floor of the scale along the normal
    c_min: float = 0.25  # surfel kernel: |cos incidence| floor of the in-plane footprint stretch
    surfel_fit: bool = False  # surfel kernel: centre on the plane fitted to the sample and its 4 neighbours
    edge_abs: float = 0.0  # metres; surfel kernel: edge tolerance = disc_k (alpha r + beta) + edge_abs
    block: bool = True  # each sample's depth from a plane fitted over its s x s footprint (normals from the neighbours')
    block_k: float = 2.0  # footprint plane fit accepted when its residual RMS <= block_k sigma_r + block_abs
    block_abs: float = 0.0005  # metres
    block_sel: float = 0.05  # footprint pixels within block_sel r + 4 sigma_r of its median depth are fitted
    block_inverse: bool = True  # the footprint plane is fitted to inverse depth (unbiased on oblique planes)
    radial: str = "fit"  # radial kernel scale: "model" = alpha r + beta; "fit" = fitted to each frame's depth
    disc_k: float = 3.0  # surfel kernel: edge/corner if a sample is farther than disc_k (alpha r + beta) + edge_abs
    # from the line through its two neighbours (per image axis)


@dataclass(frozen=True)
class OccupancyParams:
    """Decision rule and thresholds (defaults and reasons: docs/mapping.md).

    ``rule = "frequency"`` (default): occupied iff ``N / max(O, 1) - lambda_n F / max(O, 1) >= nu``.
    ``rule = "score"`` (the paper's): with ``g = A / max(N, 1) - lambda_f F / max(O, 1)``, occupied iff
    N > 0 and ``g >= tau_s``, or ``g >= tau_w`` with ``F / max(O, 1) <= gamma_f``.
    """

    rule: str = "frequency"
    nu: float = 0.06  # frequency rule: least signed share of a voxel's valid observations that saw surface in it
    lambda_n: float = 0.1  # frequency rule: weight of the free-space share
    lambda_f: float = 1.0  # weight of the free-space ratio in g
    tau_s: float = 0.12  # strong support: accepted whatever the free-space ratio
    tau_w: float = 0.04  # weak support: accepted only if F / max(O, 1) <= gamma_f
    gamma_f: float = 0.6  # largest admissible free-space ratio for weak support
