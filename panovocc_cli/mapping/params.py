"""The mapper's geometric parameters, in a module light enough for the CLI to read its defaults.

Defaults and the reasons for them: docs/mapping.md ("Defaults and why", "Quality").
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config import DEFAULT_VOXEL_SIZE, MAX_VOXEL_SIZE, option

# the values each choice field takes: the one list the options, the mapper's checks and the export read
KERNELS = ("psvf", "point")  # GeometryParams.kernel
RADIAL = ("fit", "model")  # GeometryParams.radial
EXTENTS = ("surfel", "box", "centre")  # GeometryParams.extent
RULES = ("frequency", "score")  # OccupancyParams.rule


@dataclass(frozen=True)
class GeometryParams:
    """Parameters of the geometry contributor (defaults and reasons: docs/mapping.md)."""

    voxel_size: float = option(DEFAULT_VOXEL_SIZE, min=0, min_open=True, max=MAX_VOXEL_SIZE,
                               help="Voxel edge length h, metres.")
    stride: int = 4  # pixels between samples of the kernel lift
    kernel: str = option("psvf", choices=KERNELS,
                         help="Surface kernel: psvf (anisotropic Gaussian) or point (ablation).")
    alpha: float = option(0.0025, min=0,
                          help="Radial kernel scale alpha in sigma_r = alpha r + beta (dimensionless).")
    beta: float = option(0.0025, min=0, help="Radial kernel scale beta, metres.")
    # Mahalanobis truncation radius (of the tangential Gaussian for box / surfel)
    kappa: float = option(1.5, min=0, min_open=True, max=10, help="Mahalanobis truncation radius kappa (dimensionless).")
    w_pole: float = 0.5  # latitude weight at the poles (1 at the equator)
    r_half: float = 8.0  # metres; range weight 1 / (1 + r / r_half)
    eps_abs: float = option(0.07, min=0, help="Free-space margin eps_abs in eps(r) = eps_abs + eps_rel r, metres.")
    eps_rel: float = option(0.01, min=0, help="Free-space margin eps_rel (dimensionless, per metre of range).")
    stable_k: float = 2.0  # neighbour depths within stable_k * eps(r) count as stable
    min_range: float = 0.1  # metres; depths and voxels nearer than this are ignored
    max_range: float = option(12.0, min=0, min_open=True,
                              help="Depths and voxels farther than this are ignored, metres.")
    extent: str = "surfel"  # "surfel": kernel on the local surface plane, factor P(plane through the voxel box);
    # "box": radial factor = P(ray coordinate in the voxel's chord); "centre": the paper's
    n_fill: float = 0.4  # a frame counts in N where a measurement lies in the voxel or its support dA >= n_fill
    hit_k: float = 1.0  # surfel kernel: a measurement also counts in N for the voxels of x +- hit_k s n where
    hit_max: float = 0.0005  # metres; ... s (the fitted position's std along n) <= hit_max: planes on a voxel face
    hit_amb: float = 1.0  # surfel kernel: a measurement with s > hit_max within hit_amb s of a voxel face counts in
    # no voxel's N (ambiguous side; 0 = where it fell)
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
    offsets: bool = option(False, help="Record the surface-offset channel P (each frame's mean measured position, "
                                       "normal and its square per voxel; what --resolve reads; implied by "
                                       "--resolve; docs/mapping.md).")
    observe_hits: bool = True  # a frame that counts in a voxel's N also counts in its O (it observed the voxel),
    # so N <= O and N / O is the share of observations that saw surface; False: O counts valid comparisons of
    # the voxel's centre only (maps made before this rule, whose config.json has no such key)


@dataclass(frozen=True)
class OccupancyParams:
    """Decision rule and thresholds (defaults and reasons: docs/mapping.md).

    ``rule = "frequency"`` (default): occupied iff ``N / max(O, 1) - lambda_n F / max(O, 1) >= nu``.
    ``rule = "score"`` (the paper's): with ``g = A / max(N, 1) - lambda_f F / max(O, 1)``, occupied iff
    N > 0 and ``g >= tau_s``, or ``g >= tau_w`` with ``F / max(O, 1) <= gamma_f``.
    ``spill > 0``: then the spill thinning of :func:`~panovocc_cli.mapping.export.thin_spill` (needs the voxels'
    face neighbours; maps made before it, whose config.json has no ``spill`` key, export without it).
    ``resolve``: the face resolution of :func:`~panovocc_cli.mapping.export.resolve_faces` (needs the face
    neighbours and the surface-offset channel P; off by default, and for maps made before it).
    """

    rule: str = option("frequency", choices=RULES,
                       help="Occupancy rule: frequency (N/O - lambda_n F/O >= nu) or score (the paper's g with "
                            "tau_s, tau_w, gamma_f).")
    nu: float = option(0.06, min=0, max=1, help="Frequency rule: least share of valid observations that saw "
                                                 "surface in the voxel (0..1).")
    lambda_n: float = option(0.1, min=0, help="Frequency rule: weight of the free-space share F/O.")
    lambda_f: float = option(1.0, min=0, help="Score rule: weight lambda_f of the free-space ratio in the signed score.")
    tau_s: float = option(0.12, help="Score rule: strong support threshold tau_s on g (per-frame support units).")
    tau_w: float = option(0.04, help="Score rule: weak support threshold tau_w on g.")
    gamma_f: float = option(0.6, min=0, max=1, help="Score rule: largest free-space ratio F/O for weak support (0..1).")
    spill: float = option(0.0, min=0, max=1,
                          help="Spill thinning (0 = off): an occupied voxel in a sheet whose support share A/O is "
                               "below this times an occupied face neighbour's, with no occupied voxel on its "
                               "other side, is that neighbour's surface smeared over the face by pose error (0..1; "
                               "docs/mapping.md).")
    spill_between: float = option(0.5, min=0, max=1,
                                  help="Spill thinning: the same between two occupied face neighbours, against the "
                                       "smaller of their support shares (0..1).")
    resolve: bool = option(False, help="Face resolution: of two occupied face neighbours holding one surface "
                                       "smeared over their shared face (seen from one side), keep the one holding "
                                       "the pair's mean measured position (needs the map's channel P; "
                                       "docs/mapping.md).")
    resolve_normal: float = option(0.9, min=0, max=1,
                                   help="Face resolution: least mean normal component along the face's axis (0..1).")
    resolve_offset: float = option(0.2, min=0, max=0.5,
                                   help="Face resolution: least mean offset from each voxel's centre towards the "
                                        "shared face, in voxel edges (0..0.5).")
    resolve_gap: float = option(4.0, min=0,
                                help="Face resolution: the two voxels' mean positions must be closer than this times "
                                     "the spread of the frames' mean positions (one smeared surface, not two; 0 = "
                                     "no such test).")
    resolve_behind: float = option(0.0, min=0,
                                   help="Face resolution: a voxel on the cameras' side of the pair loses to the one "
                                        "behind it only when the pair's mean position lies behind the face by at "
                                        "least this many standard errors of that mean (0 = by any amount; 1 was tried "
                                        "and not kept: docs/slam.md, \"Translation and rotation apart\").")
    spill_support: float = option(0.7, min=0,
                                  help="Spill thinning: a spill's support per hit frame A/N is at least this times "
                                       "its neighbour's (a voxel a surface only clips is kept).")
