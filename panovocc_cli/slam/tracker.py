"""Panoramic RGB-D tracking with keyframes, loop closure and pose-graph optimisation.

:class:`Tracker` estimates ``T_world_cam`` of each ERP depth frame online (the world frame is the
first placed frame's camera frame turned +Z up, :data:`LEVEL_FIRST`, unless the caller gives the first placed
frame's pose, ``T_world_first``):

1. **Tracking, frame to keyframe.** The frame's points (every ``stride``-th pixel, ranges within
   ``(min_range_m, max_range_m)``) are downsampled to ``voxel_m`` and registered to the current
   keyframe (:mod:`.registration`: small_gicp's GICP or Open3D's point-to-plane ICP) from the
   constant-velocity prediction and, unless that fits above ``1 - guess_margin``, from the previous
   pose (no motion: hard turns and stops break the constant velocity); the no-motion result wins when
   it fits better by ``guess_margin``. A result whose inlier fraction is below ``min_fitness`` or that
   corrects its guess by more than ``max_step_m`` / ``max_step_deg`` is a tracking failure.
2. **Relocalisation.** A failure, and a fit below ``kf_fitness``, relocalise: the frame is
   registered to the ``reloc_candidates`` keyframes nearest the prediction, from the prediction and
   from four headings about the keyframe's vertical axis (screened at ``reloc_voxel_m``; the
   ``reloc_refine`` best distinct hypotheses refined within ``loop_max_corr_m``, which scores them).
   The best is accepted only when it scores ``reloc_fitness`` and leads every distinct hypothesis
   (``reloc_distinct_m`` / ``reloc_distinct_deg`` apart) by ``reloc_margin``; a poor tracking fit
   competes and stands unless beaten by that margin. Otherwise the frame is **lost** (not placed):
   look-alike places are refused, not guessed. A frame with fewer than ``min_points`` downsampled
   points (few valid depths) is lost without trying.
3. **Keyframes.** A frame becomes a keyframe when it is ``kf_trans_m`` or ``kf_rot_deg`` from its
   keyframe, when the fit drops below ``kf_fitness``, or after a relocalisation. Consecutive
   keyframes are joined by an odometry edge (the registration, with Open3D's information matrix);
   each keyframe keeps its path length along those edges.
4. **Loop closure.** Two keyframes a path length L apart are uncertain relative to each other by
   sigma = max(``odom_min_sigma_m``, ``odom_sigma_per_m`` L) (and likewise in degrees), and along the
   up axis by max(``odom_min_sigma_m``, ``odom_sigma_up_per_m`` L): a panorama sees floor and ceiling, which
   hold the height (measured: under 3e-5 m / m over the building's 1.5 km). A new keyframe is
   compared with older keyframes (at least ``loop_min_gap`` keyframes back) within ``loop_radius_m``
   plus ``loop_sigmas`` sigmas of it, and as close along the up axis with the up sigma (the mean of every
   keyframe's camera up, -y, so far: a storey above or below is no candidate) (nearest first, at most ``loop_candidates``); a candidate is
   verified by registration from the current estimate and accepted at fitness >= ``loop_fitness``
   (``loop_max_corr_m``) when its correction of the estimate lies within ``loop_sigmas`` sigmas.
   Accepted candidates become uncertain edges. With ``loop_linked`` = L > 0 a candidate is skipped unverified
   when a loop edge already joins the new keyframe or one of the L before it to a keyframe within L of the
   candidate (the odometry links the two places already): where a walk runs back through seen corridors,
   a keyframe then registers about one candidate in L instead of ``loop_candidates`` (default L = 3; 0 verifies
   every candidate, as before 2026-12-05).
5. **Pose-graph optimisation** (:mod:`.posegraph`, ``optimiser``): with ``isam2`` every new keyframe adds its
   node and edges to GTSAM's iSAM2 (incremental; robust Geman-McClure kernel on loop edges), with ``open3d``
   the whole graph is solved by Open3D's ``global_optimization`` (line-process pruning of wrong loop edges).
   The keyframe poses are read back (iSAM2: after further updates until none relinearises) when a new loop
   edge disagrees with the estimate by more than ``loop_optimise_m`` / ``loop_optimise_deg`` (an agreeing
   edge waits for the next one); keyframe poses move, and every placed frame follows its keyframe
   (``T_world_frame = T_world_kf · T_kf_frame``).

6. **Final refinement** (:meth:`Tracker.finish`, ``refine*``): every keyframe registered to its
   ``refine_partners`` nearest older keyframes within ``refine_radius_m`` (a KD-tree), the odometry edges
   registered again, the graph optimised in one batch (GTSAM's Levenberg-Marquardt with the iSAM2 factors, or
   Open3D's); ``refine_passes`` passes, and optionally one every
   ``refine_every`` keyframes. Every frame it moved by more than ``final_revise_m`` / ``final_revise_deg``
   is returned as a revision. With ``heading_prior`` (off by default; iSAM2 only) the batch solve also holds
   each keyframe's heading to the walls it sees (:mod:`.heading`, :meth:`Tracker._manhattan_priors`): a
   building's stairs turn each floor by a few hundredths of a degree, which no loop sees. With ``level_prior``
   (off by default; iSAM2 only) it holds each keyframe's roll and pitch to the floors and ceilings it sees: a long
   corridor otherwise tilts a floor by a hundredth of a degree or two.
7. **Bounded store.** Only the ``kf_held`` keyframes used last keep their registration structures; the
   others keep their downsampled points, the structures rebuilt from them (the same bytes) when needed.
   Loop candidates come from a KD-tree over the keyframe positions (:meth:`Tracker._loop_candidates`).

Every frame pose that an optimisation moves by more than ``revise_trans_m`` or ``revise_rot_deg``
from the pose last handed out is returned in :attr:`TrackStep.revisions`: the caller sends it to
its map (``Mapper.revise``). The poses handed out (:meth:`Tracker.committed`) are what the map was
built with; they differ from the optimiser's by at most those thresholds. With ``revise_per_frame`` = k > 0
a frame carries at most k of them, the largest corrections first, and the others wait for later frames
(a late loop closure that moves thousands of frames then costs the map k revisions a frame, not one stall;
the poses handed out in the meantime differ from the optimiser's by more); :meth:`Tracker.finish` hands
out every one left. Maths only: no files, no printing (Open3D's console output is silenced).
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import numpy as np

from ..geometry import erp
from ..geometry.drift import so3_exp
from .posegraph import OPTIMISERS, IncrementalGraph, solve_batch, solve_open3d
from .registration import BACKENDS, Cloud, Registration, erp_points

TRACKED, KEYFRAME, RELOCALISED, LOST = "tracked", "keyframe", "relocalised", "lost"

LEVEL_REFERENCES = ("keyframes", "world")  # SlamParams.level_reference
PRESETS = {
    "default": {},
    # a multi-storey walk with long corridors (docs/slam.md, "The building's tilt, and a level prior"): the final
    # refinement's pairs within 1 m (longer ones along a corridor stretch it), each keyframe's heading held to its
    # walls and its roll and pitch to its floors and ceilings. Not every scene's default: on the Results houses 2
    # and 3 it costs a point of IoU (docs/slam.md, "The building recipe as every scene's default?").
    "building": {"refine_radius_m": 1.0, "heading_prior": True, "level_prior": True},
}
"""Named sets of :class:`SlamParams` fields (``map --poses slam --slam-preset NAME``), applied to the defaults
before ``--slam-params``."""
# SlamParams.check's ranges: lengths, angles and sigmas that must be > 0; thresholds that may be 0 (0 turns a check
# off where the field says so); inlier and normal shares in [0, 1]; counts and their least values
POSITIVE = ("isam_relinearize", "voxel_m", "max_range_m", "max_corr_m", "max_step_m", "max_step_deg", "kf_trans_m",
            "kf_rot_deg", "loop_radius_m", "loop_max_corr_m", "odom_sigma_per_m", "odom_sigma_deg_per_m",
            "odom_min_sigma_m", "odom_min_sigma_deg", "loop_sigmas", "reloc_voxel_m", "refine_radius_m",
            "heading_sigma_deg", "heading_max_deg", "level_sigma_deg", "level_max_deg")
NON_NEGATIVE = ("min_range_m", "refine_corr_m", "guess_margin", "check_m", "check_deg", "odom_sigma_up_per_m",
                "loop_optimise_m", "loop_optimise_deg", "reloc_margin", "reloc_distinct_m", "reloc_distinct_deg",
                "refine_max_m", "refine_max_deg", "revise_trans_m", "revise_rot_deg", "final_revise_m",
                "final_revise_deg")
SHARES = ("min_fitness", "kf_fitness", "loop_fitness", "reloc_fitness", "refine_fitness", "heading_min_share",
          "level_min_share")
COUNTS = {"stride": 0, "min_points": 0, "loop_min_gap": 0, "loop_candidates": 0, "loop_linked": 0,
          "refine_partners": 0, "refine_every": 0, "revise_per_frame": 0, "isam_iterations": 1, "isam_skip": 1,
          "max_iterations": 1, "reloc_candidates": 1, "reloc_refine": 1, "refine_passes": 1, "heading_reference": 1,
          "threads": 1, "kf_held": 2}
LEVEL_FIRST = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
"""Default pose of the first placed frame: the world is its camera frame turned so that world +Z is the
camera's up (−y) and world +Y its forward (+z), i.e. a level first panorama gives a +Z-up world (the
toolkit's convention) with the origin at the first camera centre."""


@dataclass
class SlamParams:
    """Parameters of the SLAM front end (units in the names; defaults tuned on the synthetic scenes of
    seeds 0 and 1 at 512 x 256, docs/slam.md)."""

    backend: str = "small_gicp"
    optimiser: str = "isam2"        # pose graph: GTSAM iSAM2 (incremental) or "open3d" (whole graph each time)
    isam_relinearize: float = 1e-4  # iSAM2: relinearise a variable whose update exceeds this (rad, m; 1e-3: 2e-6 from LM)
    isam_iterations: int = 10       # iSAM2: at most this many further updates when the poses are read back
    isam_skip: int = 10             # iSAM2: a keyframe's update considers relinearising every this many (the read-back's always)
    voxel_m: float = 0.1
    stride: int = 0                 # pixel stride of the point cloud; 0 = max(1, W // 256)
    min_range_m: float = 0.2
    max_range_m: float = 10.0
    max_corr_m: float = 0.5         # tracking correspondence distance (coarse stage)
    refine_corr_m: float = 0.1      # a refinement stage of each tracking registration at this correspondence distance
    #                                 (0 = none; 0.1 since 2026-12-05: tuning scenes' refined ATE 1.75/1.34/1.95 ->
    #                                 1.17/0.88/0.92 mm, clean depth 1.09/0.75/1.30 -> 0.58/0.29/0.55; tracking +15 % CPU)
    max_iterations: int = 30
    min_points: int = 300           # downsampled points below which a frame cannot be placed
    min_fitness: float = 0.5        # inlier fraction below which tracking has failed
    max_step_m: float = 1.0         # largest correction of an initial guess accepted while tracking
    max_step_deg: float = 90.0      # (a panorama registers across large turns: a turn is a shift of columns)
    zero_motion_init: bool = True   # also register from the previous pose (no motion); it wins when it fits
    guess_margin: float = 0.05      # better than the prediction's by this much
    kf_trans_m: float = 0.4
    kf_rot_deg: float = 20.0
    kf_fitness: float = 0.85
    check_m: float = 0.01           # frame-to-keyframe vs frame-to-previous-frame disagreement that promotes
    check_deg: float = 0.5          # the previous frame to a keyframe (0 = no check)
    loop_radius_m: float = 1.5      # keyframes this close (plus the odometry's uncertainty) may overlap
    loop_min_gap: int = 6           # keyframes between a loop's two ends
    loop_candidates: int = 3
    loop_linked: int = 3            # skip a candidate j when a loop edge already joins one of the last this many
                                    # keyframes to a keyframe within this many of j (0 = verify every candidate;
                                    # 3: the building's late keyframes cost 1.14x its early ones, not 2.13x)
    loop_fitness: float = 0.6
    loop_max_corr_m: float = 0.1   # loop verification, edge information, relocalisation scores (0.2: ATE 12.5 -> 8.7 mm, house 0)
    odom_sigma_per_m: float = 0.02  # odometry drift (1 sigma) per metre travelled: translation, m / m,
    odom_sigma_deg_per_m: float = 0.5   # and rotation, degrees / m
    odom_sigma_up_per_m: float = 3e-4  # and along the cameras' up axis, m / m (floor and ceiling hold the height:
    #                                 a loop candidate a storey above or below is out of reach; 0 = as translation)
    odom_min_sigma_m: float = 0.05  # floors of the relative uncertainty of two keyframes
    odom_min_sigma_deg: float = 2.0
    loop_sigmas: float = 3.0        # a loop's correction must lie within this many sigmas of the odometry
    loop_optimise_m: float = 0.01   # optimise at once only when a new loop edge disagrees with the estimate
    loop_optimise_deg: float = 0.3  # by more than this (else it waits in the graph for the next optimisation)
    reloc_candidates: int = 5
    reloc_fitness: float = 0.6      # inlier fraction within loop_max_corr_m of the best relocalisation,
    reloc_margin: float = 0.1       # and its lead over every distinct pose hypothesis
    reloc_distinct_m: float = 0.3   # hypotheses further apart than this, or than reloc_distinct_deg, are distinct
    reloc_distinct_deg: float = 15.0
    reloc_voxel_m: float = 0.25     # relocalisation screens its hypotheses with the frame at this voxel size,
    reloc_refine: int = 4           # then refines this many distinct ones at full resolution
    refine: bool = True             # a final refinement of the keyframe poses against each other (Tracker.finish)
    refine_passes: int = 2          # final refinements, each registering the pairs again from the last one's poses
    refine_every: int = 0           # and one after every this many new keyframes (0 = only the final one)
    refine_radius_m: float = 3.0    # keyframes this close are registered to each other,
    refine_partners: int = 4        # each to at most this many nearest older ones (tuned on homes 5, 6, house 5)
    refine_fitness: float = 0.5     # a pair is an edge when this share of points matches within loop_max_corr_m
    refine_max_m: float = 0.1       # and its registration corrects the estimate by at most this
    refine_max_deg: float = 2.0
    revise_trans_m: float = 0.01    # a frame moved further than this by an optimisation is revised in the map
    revise_rot_deg: float = 0.2
    revise_per_frame: int = 0       # at most this many of those revisions handed out with a frame, the largest
    #                                 corrections first, the rest later (0: every one at once, as before)
    final_revise_m: float = 0.0005  # after the final refinement: finer (the poses handed out are the refined ones)
    final_revise_deg: float = 0.01
    heading_prior: bool = False     # Manhattan heading: the final refinement pulls each keyframe's wall directions
    #                                 (mod 90 deg, about the up axis) to the first keyframes' (:mod:`.heading`);
    #                                 for buildings of perpendicular walls (a storey of stairs turns a floor by
    #                                 0.05-0.09 deg otherwise: docs/slam.md "The building's heading"); off: none
    heading_sigma_deg: float = 0.2  # its standard deviation a keyframe (the walls' scatter: 0.014-0.036 deg; 0.05 was
    #                                 worse on the tuning scenes, whose registrations hold the heading better)
    heading_max_deg: float = 1.0    # a keyframe whose walls read further than this from the reference gets none
    heading_min_share: float = 0.3  # nor one whose horizontal normals lie within 2 deg of its heading less often
    heading_reference: int = 8      # the reference: the circular mean of the first this many keyframes' headings
    #                                 (and the mean of their verticals, for the level prior)
    level_prior: bool = False       # level floors: the final refinement pulls each keyframe's vertical (the normal of
    #                                 the floors and ceilings it sees, :func:`.heading.floor_vertical`) onto the first
    #                                 keyframes'; roll and pitch only (a 94 m corridor otherwise leaves a floor tilted
    #                                 by 0.01-0.02 deg: docs/slam.md "The building's tilt"); off: none
    level_sigma_deg: float = 0.2    # its standard deviation a keyframe (the verticals' scatter: 0.002-0.018 deg)
    level_max_deg: float = 1.0      # a keyframe whose vertical reads further than this from the reference gets none
    level_min_share: float = 0.3    # nor one whose near-vertical normals lie within 0.5 deg of it less often
    level_reference: str = "keyframes"  # the vertical the keyframes are held to: the first heading_reference
    #                                 keyframes' mean ("keyframes"), or the world's +Z ("world": a world given with
    #                                 --first-pose whose z is up, a survey's or the reference trajectory's)
    threads: int = 1                # registration threads (1: the same frames give the same bytes)
    kf_held: int = 32               # keyframes that keep their registration structures (the last used; >= 2)

    def check(self) -> "SlamParams":
        """The parameters themselves, or ValueError naming the first one outside its range (every number finite;
        :data:`POSITIVE`, :data:`NON_NEGATIVE`, :data:`SHARES`, :data:`COUNTS`), an unknown choice or a
        contradiction."""
        for name in POSITIVE + NON_NEGATIVE + SHARES:
            v = getattr(self, name)
            lo_ok = v > 0 if name in POSITIVE else v >= 0
            if not (math.isfinite(v) and lo_ok and (name not in SHARES or v <= 1)):
                what = "> 0" if name in POSITIVE else "in [0, 1]" if name in SHARES else ">= 0"
                raise ValueError(f"{name} must be a finite number {what}, got {v!r}")
        for name, least in COUNTS.items():
            if getattr(self, name) < least:
                raise ValueError(f"{name} must be >= {least}, got {getattr(self, name)!r}")
        if not self.min_range_m < self.max_range_m:
            raise ValueError(f"min_range_m must be below max_range_m, got {self.min_range_m} and {self.max_range_m}")
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.optimiser not in OPTIMISERS:
            raise ValueError(f"optimiser must be one of {OPTIMISERS}, got {self.optimiser!r}")
        if self.heading_prior and self.optimiser != "isam2":
            raise ValueError("heading_prior needs the isam2 optimiser (GTSAM's batch solve of the refinement)")
        if self.level_prior and self.optimiser != "isam2":
            raise ValueError("level_prior needs the isam2 optimiser (GTSAM's batch solve of the refinement)")
        if self.level_reference not in LEVEL_REFERENCES:
            raise ValueError(f"level_reference must be one of {LEVEL_REFERENCES}, got {self.level_reference!r}")
        return self


@dataclass
class TrackStep:
    """What :meth:`Tracker.track` found for one frame.

    frame_id : int; status : ``tracked`` | ``keyframe`` | ``relocalised`` | ``lost``
    T_world_cam : (4, 4) float64 or None (lost: not placed)
    fitness : float, inlier fraction of the accepted registration (0 when lost)
    revisions : list of (frame_id, (4, 4) float64): earlier frames an optimisation moved
    loops : list of (keyframe frame id, keyframe frame id) loop edges added at this frame
    reason : str, why a lost frame was lost ("" otherwise)
    """

    frame_id: int
    status: str
    T_world_cam: np.ndarray | None
    fitness: float = 0.0
    revisions: list = field(default_factory=list)
    loops: list = field(default_factory=list)
    reason: str = ""

    @property
    def placed(self) -> bool:
        return self.T_world_cam is not None


@dataclass
class _Keyframe:
    frame_id: int
    cloud: Cloud
    T_world: np.ndarray
    odo_m: float = 0.0  # path length along the odometry edges from the first keyframe, metres


def _angle_deg(R: np.ndarray) -> float:
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def _yaw(angle: float) -> np.ndarray:
    """(4, 4) rotation by ``angle`` radians about the camera's vertical (y) axis: a change of heading."""
    T = np.eye(4)
    T[:3, :3] = so3_exp([0.0, angle, 0.0])
    return T


def _correction(A: np.ndarray, B: np.ndarray, trans_m: float, rot_deg: float) -> float | None:
    """None when pose B is within ``trans_m`` and ``rot_deg`` of A (:func:`_differs` is its negation), else how
    far: the larger of translation / ``trans_m`` and angle / ``rot_deg`` (a revision's rank)."""
    D = np.linalg.inv(A) @ B
    t, r = float(np.linalg.norm(D[:3, 3])), _angle_deg(D[:3, :3])
    if not (t > trans_m or r > rot_deg):
        return None
    return max(t / trans_m if trans_m > 0 else np.inf, r / rot_deg if rot_deg > 0 else np.inf)


def _differs(A: np.ndarray, B: np.ndarray, trans_m: float, rot_deg: float) -> bool:
    return _correction(A, B, trans_m, rot_deg) is not None


class Tracker:
    """Online pose estimation for one ERP RGB-D stream (module docstring).

    Parameters
    ----------
    width, height : ERP size in pixels (W = 2 H)
    params : SlamParams
    T_world_first : (4, 4) float64, pose given to the first placed frame (default :data:`LEVEL_FIRST`), or
        (n, 4, 4) float64, one per frame id: the first placed frame ``k`` gets ``T_world_first[k]`` (a
        reference trajectory: its world then holds every later frame,
        ``T_world_cam(i) = T_world_first[k] · T_slam(k)⁻¹ · T_slam(i)``)
    """

    def __init__(self, width: int, height: int, params: SlamParams | None = None, T_world_first=None):
        self.params = (params or SlamParams()).check()
        p = self.params
        self.stride = p.stride if p.stride > 0 else max(1, width // 256)
        self._rays = erp.ray_directions(width, height)
        self._shape = (height, width)
        self.reg = Registration(p.backend, p.voxel_m, p.max_iterations, p.threads)
        self._screen = Registration(p.backend, p.reloc_voxel_m, 10, p.threads)  # screening: 10 iterations
        self.T_world_first = LEVEL_FIRST.copy() if T_world_first is None else np.asarray(T_world_first, np.float64)
        self.keyframes: list[_Keyframe] = []
        self._held: OrderedDict[int, None] = OrderedDict()  # keyframes holding registration structures, last used last
        self._edges: list[tuple[int, int, np.ndarray, np.ndarray, bool]] = []  # (source kf, target kf, T_t_s, info, uncertain)
        self._placed: dict[int, tuple[int, np.ndarray]] = {}   # frame id -> (keyframe index, T_kf_frame)
        self._committed: dict[int, np.ndarray] = {}
        self._loop_ends: dict[int, list[int]] = {}  # keyframe -> the older keyframes its loop edges join it to
        self.loops_skipped = 0  # candidates not verified (loop_linked)
        self.heading = None  # the last refinement's heading priors (heading_prior), :meth:`_manhattan_priors`
        self.heading_corrections = None  # and each keyframe's correction, radians (nan: no heading read)
        self.level = None  # the last refinement's level priors (level_prior): keyframes, corrections' median, largest
        self.level_corrections = None  # each keyframe's tilt correction, radians (nan: no vertical read)
        self._pending: deque[int] = deque()  # frames an optimisation moved, not yet handed out (revise_per_frame), largest first
        self.lost: list[int] = []
        self.relocalised: list[int] = []
        self.loops: list[tuple[int, int]] = []
        self.optimisations = 0
        self._graph: IncrementalGraph | None = None  # iSAM2's graph (optimiser "isam2"), rebuilt after a refinement
        self._synced = 0  # edges of self._edges already in it
        self._arrays: tuple | None = None  # (optimisations, positions, up axes, path lengths): _keyframe_arrays
        self.refinements = 0
        self.rebuilds = 0  # keyframes whose registration structures were rebuilt from their points (:meth:`_cloud`)
        self._ref = 0
        self._last: tuple[int, np.ndarray] | None = None
        self._velocity = np.eye(4)
        self._prev: tuple[int, Cloud] | None = None  # the previous frame, if placed (a keyframe to promote)

    # -- state -----------------------------------------------------------------------------------
    def _add_keyframe(self, kf: _Keyframe) -> None:
        self.keyframes.append(kf)
        self._cloud(len(self.keyframes) - 1)

    def _cloud(self, k: int) -> Cloud:
        """Keyframe ``k``'s cloud ready for registration. The registration structures (small_gicp's
        covariances and KD-tree, Open3D's cloud) are held for the ``kf_held`` keyframes used last; the others
        keep only their downsampled points, and the structures are rebuilt from them when needed (the same
        bytes: :meth:`.registration.Registration.restore`), so the store grows by the points alone."""
        cloud = self.keyframes[k].cloud
        if self.reg.restore(cloud):
            self.rebuilds += 1
        self._held[k] = None
        self._held.move_to_end(k)
        while len(self._held) > max(2, self.params.kf_held):
            self.keyframes[self._held.popitem(last=False)[0]].cloud.compact()
        return cloud

    def memory(self) -> dict:
        """The keyframe store: ``points`` (bytes of every keyframe's downsampled points, 24 a point), ``held``
        (keyframes with registration structures) and ``held_bytes`` (those structures' arrays, KD-trees not
        counted), ``keyframes``, ``edges``, ``frames`` (placed frames)."""
        return {"points": int(sum(kf.cloud.points.nbytes for kf in self.keyframes)), "held": len(self._held),
                "held_bytes": int(sum(self.keyframes[k].cloud.structure_bytes() for k in self._held)),
                "keyframes": len(self.keyframes), "edges": len(self._edges), "frames": len(self._placed)}

    def pose(self, frame_id: int) -> np.ndarray:
        """Current estimate (4, 4) of a placed frame: its keyframe's optimised pose times its offset."""
        k, T_kf = self._placed[int(frame_id)]
        return self.keyframes[k].T_world @ T_kf

    def committed(self) -> dict[int, np.ndarray]:
        """Frame id -> (4, 4) float64 pose last handed out (to the map), for every placed frame."""
        return {k: v.copy() for k, v in sorted(self._committed.items())}

    # -- one frame ---------------------------------------------------------------------------------
    def track(self, frame_id: int, depth: np.ndarray) -> TrackStep:
        """Place frame ``frame_id`` from its depth (H, W) float32 metres, radial, 0 = invalid."""
        p = self.params
        fid = int(frame_id)
        depth = np.asarray(depth)
        if depth.shape != self._shape:
            raise ValueError(f"frame {fid}: depth shape {depth.shape}, expected {self._shape}")
        cloud = self.reg.prepare(erp_points(depth, self._rays, self.stride, p.min_range_m, p.max_range_m))
        if len(cloud) < p.min_points:
            return self._lose(fid, f"few valid depths ({len(cloud)} points after downsampling, need {p.min_points})")
        if not self.keyframes:
            first = self.T_world_first if self.T_world_first.ndim == 2 else self.T_world_first[fid]
            self._add_keyframe(_Keyframe(fid, cloud, first.copy()))
            return self._place(fid, 0, np.eye(4), KEYFRAME, 1.0, cloud)
        last = self._last[1] if self._last is not None else self.keyframes[self._ref].T_world
        guesses = [last @ self._velocity]  # constant velocity
        if p.zero_motion_init and _differs(guesses[0], last, 0.05, 2.0):
            guesses.append(last)  # no motion: where a turn or a stop breaks the constant velocity
        kf = self.keyframes[self._ref]
        r, init = self._best_fit(self._cloud(self._ref), cloud, [np.linalg.inv(kf.T_world) @ g for g in guesses])
        pred = kf.T_world @ init  # the guess that won
        status, k = TRACKED, self._ref
        prev = self._prev
        if p.check_m > 0 and prev is not None and prev[0] == fid - 1 and prev[0] != kf.frame_id \
                and self._placed[prev[0]][0] == self._ref:
            # consistency check against the previous frame (short baseline): where the view changed a lot
            # since the keyframe (a doorway, a corner) the two disagree; the previous frame then becomes a
            # keyframe and this frame keeps its registration to it, unless that fits worse than the
            # keyframe's (after a fast turn the short baseline's registration can end in a wrong minimum:
            # 24 degrees off at 0.79 against the keyframe's 1.00, the building's frame 6,126)
            T_prev = self.pose(prev[0])
            r2 = self._register(prev[1], cloud, np.linalg.inv(T_prev) @ pred)
            if r2.fitness >= max(p.min_fitness, r.fitness) and np.all(np.isfinite(r2.T_target_source)) and _differs(
                    kf.T_world @ r.T_target_source, T_prev @ r2.T_target_source, p.check_m, p.check_deg):
                k = self._promote_previous()
                kf, r, init = self.keyframes[k], r2, np.linalg.inv(T_prev) @ pred
        tracked = (k, r) if self._accept(r, init, p.min_fitness) else None
        if tracked is None or r.fitness < p.kf_fitness:
            # failed, or a poor fit (after a fast turn or a jump the guesses may end in a wrong minimum):
            # relocalise, the tracked result competing with the other hypotheses
            found, why = self._relocalise(cloud, pred, tracked)
            if found is None:
                return self._lose(fid, f"tracking failed (fitness {r.fitness:.2f}) and relocalisation {why}")
            k, r, status = found
        return self._place(fid, k, r.T_target_source, status, r.fitness, cloud)

    def _promote_previous(self) -> int:
        """Make the previous frame a keyframe (odometry edge from its keyframe); returns its index."""
        p = self.params
        fid, cloud = self._prev
        k, T_kf = self._placed[fid]
        new = len(self.keyframes)
        self._add_keyframe(_Keyframe(fid, cloud, self.keyframes[k].T_world @ T_kf,
                                        self.keyframes[k].odo_m + float(np.linalg.norm(T_kf[:3, 3]))))
        info = self.reg.information(self._cloud(k), cloud, T_kf, p.max_corr_m)
        self._edges.append((new, k, T_kf.copy(), info, False))
        self._placed[fid] = (new, np.eye(4))
        self._ref = new
        return new

    def _register(self, target: Cloud, source: Cloud, init: np.ndarray):
        """Coarse registration (``max_corr_m``), then a refinement with ``refine_corr_m`` correspondences
        (fewer wrong matches where two rooms meet); fitness is the coarse stage's."""
        p = self.params
        r = self.reg.align(target, source, init, p.max_corr_m)
        if p.refine_corr_m > 0 and np.all(np.isfinite(r.T_target_source)):
            f = self.reg.align(target, source, r.T_target_source, p.refine_corr_m)
            if np.all(np.isfinite(f.T_target_source)) and f.fitness > 0:
                r = dataclasses.replace(f, fitness=r.fitness)
        return r

    def _best_fit(self, target: Cloud, source: Cloud, inits: list):
        """Register from each initial guess (4, 4) ``T_target_source`` in turn; returns (result, its guess).

        A later guess replaces the current best only when the best is not accepted (:meth:`_accept`) and it
        is, or when it fits better by ``guess_margin`` (the first guess, the prediction, keeps near-ties:
        tested equal on the homes); once the best fits better than ``1 - guess_margin`` no later guess can
        win, and none is tried."""
        p = self.params
        best = None
        for init in inits:
            if best is not None and best[0] and best[1].fitness > 1.0 - p.guess_margin:
                break
            r = self._register(target, source, init)
            ok = self._accept(r, init, p.min_fitness)
            if best is None or (ok and not best[0]) or (ok == best[0] and r.fitness > best[1].fitness + p.guess_margin):
                best = (ok, r, init)
        return best[1], best[2]

    def _accept(self, r, init: np.ndarray, min_fitness: float) -> bool:
        p = self.params
        if r.fitness < min_fitness:
            return False
        if not np.all(np.isfinite(r.T_target_source)):
            return False
        return not _differs(init, r.T_target_source, p.max_step_m, p.max_step_deg)

    def _lose(self, fid: int, reason: str) -> TrackStep:
        self.lost.append(fid)
        self._velocity = np.eye(4)
        self._prev = None
        return TrackStep(fid, LOST, None, reason=reason)

    def _relocalise(self, cloud: Cloud, pred: np.ndarray, tracked=None):
        """((keyframe index, RegResult, status), "") of the clearly best registration to a nearby keyframe,
        or (None, why not).

        Every hypothesis (each of the ``reloc_candidates`` keyframes nearest the prediction, from the
        prediction and from four headings; plus ``tracked``, (keyframe index, RegResult), the tracking's
        own poor fit, if any) is refined within ``loop_max_corr_m``, whose inlier fraction scores it. The
        best is accepted (status ``relocalised``) only when it reaches ``reloc_fitness`` and leads every
        *distinct* hypothesis (a world pose more than ``reloc_distinct_m`` or ``reloc_distinct_deg`` away)
        by ``reloc_margin``: in look-alike places (a symmetric room, rooms alike off a corridor) two poses
        fit about equally, and the frame is then lost rather than placed in the wrong one. Where no other
        pose beats ``tracked`` clearly, the tracked result stands (status ``tracked``): the motion guess
        breaks the tie."""
        p = self.params
        hyps = []  # (score, keyframe index, RegResult, T_world, is the tracked result)

        def add(k: int, r, is_tracked: bool):
            kf = self.keyframes[k]
            f = self.reg.align(self._cloud(k), cloud, r.T_target_source, p.loop_max_corr_m)
            if np.all(np.isfinite(f.T_target_source)):
                hyps.append((f.fitness, k, f, kf.T_world @ f.T_target_source, is_tracked))

        if tracked is not None:
            add(tracked[0], tracked[1], True)
        # screening: every hypothesis registered with a coarse copy of the frame (a wrong start costs many
        # iterations at full resolution); the best few distinct ones are then refined at full resolution
        coarse = self._screen.prepare(cloud.points)
        pos = np.array([k.T_world[:3, 3] for k in self.keyframes])
        order = np.argsort(np.linalg.norm(pos - pred[:3, 3], axis=1), kind="stable")[: p.reloc_candidates]
        screened = []
        for k in order:
            kf = self.keyframes[int(k)]
            inits = [np.linalg.inv(kf.T_world) @ pred] + [_yaw(a) for a in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi)]
            for init in inits:  # headings about the keyframe's vertical axis: a panorama's one ambiguity worth trying
                r = self._screen.align(self._cloud(int(k)), coarse, init, p.max_corr_m)
                if r.fitness >= p.min_fitness and np.all(np.isfinite(r.T_target_source)):
                    screened.append((r.fitness, int(k), r, kf.T_world @ r.T_target_source))
        kept: list = []
        for h in sorted(screened, key=lambda h: -h[0]):  # stable: the first of equals
            if len(kept) < p.reloc_refine and all(
                    _differs(h[3], g[3], p.reloc_distinct_m, p.reloc_distinct_deg) for g in kept):
                kept.append(h)
        for h in kept:
            add(h[1], h[2], False)
        if not hyps:
            return None, "found no fit"
        best = max(hyps, key=lambda h: h[0])  # the first of equals (the tracked result is first)
        rival = max((h[0] for h in hyps if _differs(best[3], h[3], p.reloc_distinct_m, p.reloc_distinct_deg)),
                    default=0.0)
        mine = [h for h in hyps if h[4]]
        if mine and (best[4] or not _differs(best[3], mine[0][3], p.reloc_distinct_m, p.reloc_distinct_deg)
                     or best[0] - mine[0][0] < p.reloc_margin):
            # the tracked result as refined within loop_max_corr_m, as every other hypothesis is handed out (its
            # fitness stays the tracking's): a poor coarse fit can rest 10 cm off where the fine one is right
            # (the first step of a clean-depth house, 0.4 m from a standing start: 127 mm off, then 0.3 mm)
            return (tracked[0], dataclasses.replace(mine[0][2], fitness=tracked[1].fitness), TRACKED), ""
        if best[0] < p.reloc_fitness:
            return None, f"found no good fit (best {best[0]:.2f})"
        if best[0] - rival < p.reloc_margin:
            return None, f"was ambiguous (best {best[0]:.2f}, another pose {rival:.2f})"
        return (best[1], best[2], RELOCALISED), ""

    def _place(self, fid: int, k: int, T_kf_frame: np.ndarray, status: str, fitness: float, cloud: Cloud) -> TrackStep:
        p = self.params
        kf = self.keyframes[k]
        T_world = kf.T_world @ T_kf_frame
        loops: list = []
        revisions: list = []
        if status == RELOCALISED:
            self.relocalised.append(fid)
        make_kf = status == RELOCALISED or (
            fid != kf.frame_id and (np.linalg.norm(T_kf_frame[:3, 3]) > p.kf_trans_m
                                    or _angle_deg(T_kf_frame[:3, :3]) > p.kf_rot_deg or fitness < p.kf_fitness))
        if make_kf:
            new = len(self.keyframes)
            self._add_keyframe(_Keyframe(fid, cloud, T_world.copy(), kf.odo_m + float(np.linalg.norm(T_kf_frame[:3, 3]))))
            info = self.reg.information(self._cloud(k), cloud, T_kf_frame, p.max_corr_m)
            self._edges.append((new, k, T_kf_frame.copy(), info, False))
            self._placed[fid] = (new, np.eye(4))
            self._ref = new
            loops, urgent = self._close_loops(new)
            self._sync()  # iSAM2: the new keyframes and edges, one update
            periodic = p.refine_every > 0 and len(self.keyframes) % p.refine_every == 0
            if periodic:  # its optimisation takes the new loop edges too
                self.refine(revise=False)
            elif urgent:
                self._optimise()
            if periodic or urgent:
                revisions = self._revisions(exclude=fid, budget=p.revise_per_frame)
            T_world = self.pose(fid)
            if status == TRACKED:
                status = KEYFRAME
        else:
            self._placed[fid] = (k, T_kf_frame.copy())
            self._ref = k
        if not revisions and self._pending:  # the corrections left over by an earlier optimisation
            revisions = self._handed_out(p.revise_per_frame)
        if self._last is not None and self._last[0] == fid - 1:
            self._velocity = np.linalg.inv(self._last[1]) @ T_world
        else:
            self._velocity = np.eye(4)
        self._last = (fid, T_world.copy())
        self._prev = (fid, cloud)
        self._committed[fid] = T_world.copy()
        return TrackStep(fid, status, T_world.copy(), float(fitness), revisions, loops)

    # -- loops and the pose graph -----------------------------------------------------------------
    def _loop_sigma(self, a: int, b: int) -> tuple[float, float]:
        """Relative uncertainty (1 sigma: metres, degrees) of keyframes ``a`` and ``b`` by odometry: grows
        with the path length between them, floored (``odom_*`` parameters)."""
        p = self.params
        L = abs(self.keyframes[a].odo_m - self.keyframes[b].odo_m)
        return max(p.odom_min_sigma_m, p.odom_sigma_per_m * L), max(p.odom_min_sigma_deg, p.odom_sigma_deg_per_m * L)

    def _loop_candidates(self, new: int, index: bool = True) -> list[int]:
        """Loop candidates of keyframe ``new`` (:meth:`_close_loops`), nearest first: keyframes at least
        ``loop_min_gap`` back within ``loop_radius_m`` plus ``loop_sigmas`` odometry sigmas, and as close along
        the up axis with the up sigma (``odom_sigma_up_per_m``), at most ``loop_candidates``. ``index``: found by a
        KD-tree over the keyframe positions within the largest such radius (that of the first keyframe, furthest
        along the path), then the exact test; else the exact test of every keyframe (the same list: tested).
        The test is vectorised over the keyframes' positions, up axes and path lengths, kept in arrays between
        optimisations (:meth:`_keyframe_arrays`): a keyframe late in a long walk costs no Python loop over
        the thousands of keyframes within that radius."""
        p = self.params
        n_old = max(0, new - p.loop_min_gap)
        if n_old == 0 or p.loop_candidates <= 0:
            return []
        pos, up, odo = self._keyframe_arrays()
        here = pos[new]
        js = np.arange(n_old)
        if index:
            far = float(np.abs(odo[:n_old] - odo[new]).max())  # the largest path length apart
            reach = float(self._loop_reach(far, p.odom_sigma_per_m))
            lo, hi = pos[:n_old].min(axis=0), pos[:n_old].max(axis=0)
            if float(np.linalg.norm(np.maximum(np.abs(lo - here), np.abs(hi - here)))) > reach:
                # the ball does not hold every keyframe (late in a long walk it does, the path-length sigma
                # growing past the map's extent: then every keyframe is tested without building the tree)
                from scipy.spatial import cKDTree

                js = np.asarray(cKDTree(pos[:n_old]).query_ball_point(here, reach * (1 + 1e-9), return_sorted=True),
                                np.int64)
        if len(js) == 0:
            return []
        d = pos[js] - here
        dist = np.sqrt((d * d).sum(axis=1))
        L = np.abs(odo[js] - odo[new])
        ok = dist <= self._loop_reach(L, p.odom_sigma_per_m)
        g = up[: new + 1].sum(axis=0)  # the mean up axis of the keyframes so far: the walk's tilts average out
        norm = float(np.sqrt(g @ g))
        if p.odom_sigma_up_per_m > 0 and norm > 1e-6 * (new + 1):  # (cameras turned every way: no common up)
            ok &= np.abs(d @ (g / norm)) <= self._loop_reach(L, p.odom_sigma_up_per_m)
        js, dist = js[ok], dist[ok]
        return js[np.lexsort((js, dist))][: p.loop_candidates].tolist()

    def _loop_reach(self, L, per_m: float):
        """How far (metres) a loop candidate may lie from a keyframe a path length ``L`` (metres, scalar or array)
        away: ``loop_radius_m`` plus ``loop_sigmas`` odometry sigmas, sigma = max(``odom_min_sigma_m``, ``per_m`` L)
        (``odom_sigma_per_m`` in position, ``odom_sigma_up_per_m`` along the up axis)."""
        p = self.params
        return p.loop_radius_m + p.loop_sigmas * np.maximum(p.odom_min_sigma_m, per_m * L)

    def _keyframe_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every keyframe's position (n, 3), camera up axis (-y, (n, 3)) in the world and path length (n,), as
        float64 arrays: extended by the keyframes added since the last call, rebuilt after an optimisation
        moved them (:meth:`_optimise`)."""
        have = 0 if self._arrays is None or self._arrays[0] != self.optimisations else len(self._arrays[1])
        if have < len(self.keyframes):
            add = self.keyframes[have:]
            rows = (np.array([kf.T_world[:3, 3] for kf in add], np.float64).reshape(-1, 3),
                    -np.array([kf.T_world[:3, 1] for kf in add], np.float64).reshape(-1, 3),
                    np.array([kf.odo_m for kf in add], np.float64))
            old = self._arrays[1:] if have else (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
            self._arrays = (self.optimisations, *(np.concatenate([a, b]) for a, b in zip(old, rows)))
        return self._arrays[1:]

    def _close_loops(self, new: int) -> tuple[list[tuple[int, int]], bool]:
        """Loop edges of keyframe ``new``: (list of (frame id, frame id), whether any needs an optimisation now).

        Candidates (:meth:`_loop_candidates`): keyframes at least ``loop_min_gap`` back whose estimated position
        is within ``loop_radius_m`` plus ``loop_sigmas`` odometry sigmas (:meth:`_loop_sigma`), nearest first.
        Verified by registration from the current estimate; accepted when ``loop_fitness`` of the points
        match within ``loop_max_corr_m`` and the correction of the estimate lies within ``loop_sigmas``
        sigmas (a look-alike place elsewhere needs a larger one)."""
        p = self.params
        cur = self.keyframes[new]
        found, urgent = [], False
        L = p.loop_linked
        for j in self._loop_candidates(new):
            if L > 0 and any(abs(b - j) <= L for a in range(max(0, new - L), new + 1) for b in self._loop_ends.get(a, ())):
                self.loops_skipped += 1  # this place is already joined to that one: the odometry links them
                continue
            kf = self.keyframes[j]
            init = np.linalg.inv(kf.T_world) @ cur.T_world
            target, source = self._cloud(j), self._cloud(new)
            r = self.reg.align(target, source, init, p.max_corr_m)
            if r.fitness < p.min_fitness or not np.all(np.isfinite(r.T_target_source)):
                continue
            r = self.reg.align(target, source, r.T_target_source, p.loop_max_corr_m)
            s_m, s_deg = self._loop_sigma(new, j)
            if r.fitness < p.loop_fitness or not np.all(np.isfinite(r.T_target_source)) or _differs(
                    init, r.T_target_source, p.loop_sigmas * s_m, p.loop_sigmas * s_deg):
                continue
            info = self.reg.information(target, source, r.T_target_source, p.loop_max_corr_m)
            self._edges.append((new, j, r.T_target_source.copy(), info, True))
            self._loop_ends.setdefault(new, []).append(j)
            found.append((cur.frame_id, kf.frame_id))
            urgent = urgent or _differs(init, r.T_target_source, p.loop_optimise_m, p.loop_optimise_deg)
        self.loops.extend(found)
        return found, urgent

    def refine(self, revise: bool = True) -> list[tuple[int, np.ndarray]]:
        """Multiway refinement of the keyframe poses against each other; returns the frames it moved
        (:attr:`TrackStep.revisions`' form).

        Every keyframe is registered to its ``refine_partners`` nearest older keyframes within
        ``refine_radius_m`` (a KD-tree over the keyframe positions) from the current estimate, within
        ``loop_max_corr_m``; a pair that matches ``refine_fitness`` of its points and corrects the estimate by
        at most ``refine_max_m`` / ``refine_max_deg`` becomes an uncertain edge. The odometry edges are
        re-registered the same way (kept certain). The graph of those edges (and the loop edges between
        pairs it did not register) is optimised (:meth:`_optimise`); every frame follows its keyframe."""
        from scipy.spatial import cKDTree

        p = self.params
        n = len(self.keyframes)
        if n < 2:
            return []
        pos = np.array([kf.T_world[:3, 3] for kf in self.keyframes])
        tree = cKDTree(pos)
        pairs: set[tuple[int, int]] = set()
        for i in range(1, n):
            near = tree.query_ball_point(pos[i], p.refine_radius_m)
            older = sorted((j for j in near if j < i), key=lambda j: (float(np.linalg.norm(pos[i] - pos[j])), j))
            pairs.update((i, j) for j in older[: p.refine_partners])
        odometry = {(s, t) for s, t, _, _, unc in self._edges if not unc}
        new_pairs = sorted(pairs - odometry)
        # every registration, in the order of its newer keyframe: each keyframe's structures are rebuilt about once
        # a pass (:meth:`_cloud` holds ``kf_held``); the edges keep their order (odometry, then the pairs sorted)
        jobs = [(e, s, t) for e, (s, t, _, _, unc) in enumerate(self._edges) if not unc]
        jobs += [((s, t), s, t) for s, t in new_pairs]
        done = {}
        for rank in sorted(range(len(jobs)), key=lambda r: (max(jobs[r][1:]), r)):
            key = jobs[rank][0]
            if isinstance(key, int):  # odometry: re-registered at the finer correspondence distance, kept certain
                s, t, T, info, _ = self._edges[key]
                a, b = self._cloud(t), self._cloud(s)
                r = self.reg.align(a, b, T, p.loop_max_corr_m)
                if r.fitness >= p.refine_fitness and np.all(np.isfinite(r.T_target_source)) and not _differs(
                        T, r.T_target_source, p.refine_max_m, p.refine_max_deg):
                    done[key] = (r.T_target_source, self.reg.information(a, b, r.T_target_source, p.loop_max_corr_m))
                continue
            s, t = key
            init = np.linalg.inv(self.keyframes[t].T_world) @ self.keyframes[s].T_world
            a, b = self._cloud(t), self._cloud(s)
            r = self.reg.align(a, b, init, p.loop_max_corr_m)
            if r.fitness < p.refine_fitness or not np.all(np.isfinite(r.T_target_source)) or _differs(
                    init, r.T_target_source, p.refine_max_m, p.refine_max_deg):
                continue
            done[key] = (r.T_target_source.copy(), self.reg.information(a, b, r.T_target_source, p.loop_max_corr_m))
        edges = []
        for e, (s, t, T, info, unc) in enumerate(self._edges):
            if not unc:
                T, info = done.get(e, (T, info))
                edges.append((s, t, T, info, False))
            elif (s, t) not in pairs:
                edges.append((s, t, T, info, True))
        edges += [(s, t, *done[(s, t)], True) for s, t in new_pairs if (s, t) in done]
        self._edges = edges
        self._optimise(batch=True)
        self.refinements += 1
        return self._revisions(exclude=-1) if revise else []

    def finish(self) -> list[tuple[int, np.ndarray]]:
        """End of the sequence: the final refinement (:meth:`refine`, when ``refine``); returns every frame
        it moved by more than ``final_revise_m`` / ``final_revise_deg`` (finer than the online thresholds:
        the poses handed out are then the refined ones)."""
        p = self.params
        if not p.refine or len(self.keyframes) < 2:
            return []
        for _ in range(max(1, p.refine_passes)):
            self.refine(revise=False)
        return self._revisions(exclude=-1, trans_m=p.final_revise_m, rot_deg=p.final_revise_deg)

    def _sync(self) -> None:
        """Optimiser ``isam2``: add the keyframes and edges not yet in the incremental graph (one iSAM2 update;
        the graph is rebuilt from every edge after a refinement replaced them). Initial poses in the first
        keyframe's frame."""
        p = self.params
        if p.optimiser != "isam2":
            return
        if self._graph is None:
            self._graph = IncrementalGraph(p.loop_max_corr_m, p.isam_relinearize, p.isam_iterations, p.isam_skip)
            self._synced = 0
        T0_inv = np.linalg.inv(self.keyframes[0].T_world)
        new = [T0_inv @ kf.T_world for kf in self.keyframes[self._graph.nodes:]]
        self._graph.add(new, self._edges[self._synced:])
        self._synced = len(self._edges)

    def _optimise(self, batch: bool = False) -> None:
        """Optimise the keyframe pose graph (:mod:`.posegraph`, ``optimiser``); keyframe poses updated in place.

        ``isam2``: the incremental graph's estimate (``batch``: GTSAM's Levenberg-Marquardt over every edge, the
        incremental graph then rebuilt from them); ``open3d``: Open3D's global optimisation of the whole graph.
        Solved in the first keyframe's frame (it is held fixed): the same relative edges give the same
        relative poses in any world (a world far from the origin, ``--first-pose``), to rounding."""
        p = self.params
        T0 = self.keyframes[0].T_world.copy()
        T0_inv = np.linalg.inv(T0)
        if p.optimiser == "open3d" or batch:
            poses = np.stack([T0_inv @ kf.T_world for kf in self.keyframes])
            if p.optimiser == "open3d":
                P = solve_open3d(poses, self._edges, p.loop_max_corr_m)
            else:
                priors = self._manhattan_priors(poses, T0_inv) if batch and (p.heading_prior or p.level_prior) \
                    else None
                P = solve_batch(poses, self._edges, p.loop_max_corr_m, priors)
            self._graph = None
        else:
            self._sync()
            P = self._graph.estimate()
        for kf, Pk in zip(self.keyframes[1:], P[1:]):
            kf.T_world = T0 @ Pk
        self.optimisations += 1

    def _manhattan_priors(self, poses: np.ndarray, T0_inv: np.ndarray) -> list:
        """The priors of a batch solve (``heading_prior``, ``level_prior``; :mod:`.heading`), from each keyframe's
        normals under its current pose.

        Heading: each keyframe's wall heading in the world against the circular mean (mod 90 deg) of the first
        ``heading_reference`` keyframes'; a keyframe within ``heading_max_deg`` of it whose normals agree
        (``heading_min_share``) gets :func:`.posegraph.heading_factor` turning it onto the reference. Level: each
        keyframe's vertical (its floors' and ceilings' normal) against the mean of the first ``heading_reference``
        keyframes' (``level_reference`` "world": the world's +Z); within ``level_max_deg`` and ``level_min_share``,
        :func:`.posegraph.level_factor` tilting it onto the reference. Their figures go to :attr:`heading` and
        :attr:`level` (keyframes with a prior, the corrections' median and largest, degrees)."""
        from .heading import cloud_normals, floor_vertical, wall_heading

        p = self.params
        _, up_all, _ = self._keyframe_arrays()
        g = up_all.sum(axis=0)
        if float(np.linalg.norm(g)) <= 1e-6 * len(up_all):
            return []
        up = g / np.linalg.norm(g)
        n_kf = len(self.keyframes)
        phi, share = np.full(n_kf, np.nan), np.zeros(n_kf)
        vert, vshare = np.full((n_kf, 3), np.nan), np.zeros(n_kf)
        for k, kf in enumerate(self.keyframes):
            n = cloud_normals(kf.cloud.points, 2.5 * self.reg.voxel_m, self.reg.threads) @ kf.T_world[:3, :3].T
            if p.heading_prior:
                phi[k], share[k] = wall_heading(n, up)
            if p.level_prior:
                v, vshare[k] = floor_vertical(n, up)
                if v is not None:
                    vert[k] = v
        R0 = T0_inv[:3, :3]  # the graph is solved in the first keyframe's frame
        out = []
        if p.heading_prior:
            out += self._heading_factors(phi, share, poses, R0 @ up)
        if p.level_prior:
            out += self._level_factors(vert, vshare, poses, R0)
        return out

    def _heading_factors(self, phi: np.ndarray, share: np.ndarray, poses: np.ndarray, up0: np.ndarray) -> list:
        from .heading import quarter_mean, wrap_quarter
        from .posegraph import heading_factor

        p = self.params
        ref = phi[: p.heading_reference]
        ref = ref[np.isfinite(ref)]
        self.heading = {"priors": 0, "median_deg": 0.0, "max_deg": 0.0}
        if len(ref) == 0:
            return []
        phi_ref = quarter_mean(ref)
        c = wrap_quarter(phi_ref - phi)  # nan where no heading
        self.heading_corrections = c
        ok = np.isfinite(c) & (share >= p.heading_min_share) & (np.abs(np.nan_to_num(c, nan=np.inf))
                                                                 <= np.radians(p.heading_max_deg))
        ok[0] = False  # the first keyframe is held by its own prior
        sigma = np.radians(p.heading_sigma_deg)
        out = [heading_factor(k, poses[k], up0, float(c[k]), sigma) for k in np.nonzero(ok)[0]]
        if len(out):
            self.heading = {"priors": len(out), "median_deg": float(np.degrees(np.median(np.abs(c[ok])))),
                            "max_deg": float(np.degrees(np.abs(c[ok]).max()))}
        return out

    def _level_factors(self, vert: np.ndarray, share: np.ndarray, poses: np.ndarray, R0: np.ndarray) -> list:
        from .heading import tilt_between
        from .posegraph import level_factor

        p = self.params
        self.level = {"priors": 0, "median_deg": 0.0, "max_deg": 0.0}
        if p.level_reference == "world":
            ref = np.array([0.0, 0.0, 1.0])
        else:
            ref = vert[: p.heading_reference]
            ref = ref[np.all(np.isfinite(ref), axis=1)]
            if len(ref) == 0:
                return []
            ref = ref.sum(axis=0) / np.linalg.norm(ref.sum(axis=0))
        tilt = np.full((len(vert), 3), np.nan)
        seen = np.all(np.isfinite(vert), axis=1)
        tilt[seen] = np.array([tilt_between(v, ref) for v in vert[seen]]).reshape(-1, 3)
        angle = np.linalg.norm(tilt, axis=1)  # nan where no vertical
        self.level_corrections = angle
        ok = seen & (share >= p.level_min_share) & (np.nan_to_num(angle, nan=np.inf) <= np.radians(p.level_max_deg))
        ok[0] = False  # the first keyframe is held by its own prior
        sigma = np.radians(p.level_sigma_deg)
        out = [level_factor(k, poses[k], R0 @ tilt[k], R0 @ ref, sigma) for k in np.nonzero(ok)[0]]
        if len(out):
            self.level = {"priors": len(out), "median_deg": float(np.degrees(np.median(angle[ok]))),
                          "max_deg": float(np.degrees(angle[ok].max()))}
        return out

    def _revisions(self, exclude: int, trans_m: float | None = None, rot_deg: float | None = None,
                   budget: int = 0) -> list[tuple[int, np.ndarray]]:
        """The placed frames (but ``exclude``) whose pose moved from the one handed out by more than ``trans_m``
        / ``rot_deg`` (default: ``revise_trans_m`` / ``revise_rot_deg``), in frame order, each now handed out at
        its new pose. ``budget`` > 0: only that many, the largest corrections first; the others wait in the
        pending list, handed out a ``budget`` a frame (:meth:`_handed_out`) or by the next scan (every scan
        lists every frame that differs, so a call without a budget, as :meth:`finish`'s, hands out all)."""
        p = self.params
        trans_m = p.revise_trans_m if trans_m is None else trans_m
        rot_deg = p.revise_rot_deg if rot_deg is None else rot_deg
        moved = []
        for fid in sorted(self._placed):
            if fid == exclude:
                continue
            T = self.pose(fid)
            c = _correction(self._committed[fid], T, trans_m, rot_deg)
            if c is not None:
                moved.append((c, fid, T))
        self._pending = deque()
        if budget > 0 and len(moved) > budget:
            moved.sort(key=lambda m: (-m[0], m[1]))
            self._pending = deque(fid for _, fid, _ in moved[budget:])
            moved = sorted(moved[:budget], key=lambda m: m[1])
        out = []
        for _, fid, T in moved:
            self._committed[fid] = T.copy()
            out.append((fid, T))
        if self._last is not None and self._last[0] in self._placed:
            self._last = (self._last[0], self.pose(self._last[0]))
        return out

    def _handed_out(self, budget: int) -> list[tuple[int, np.ndarray]]:
        """Up to ``budget`` frames of the pending list (largest correction first, as the last scan ranked them;
        frames placed before it, never the one being placed) that still differ from the pose handed out, each
        now handed out at its current pose (frame order)."""
        p = self.params
        out = []
        while self._pending and len(out) < budget:
            fid = self._pending.popleft()
            T = self.pose(fid)
            if _differs(self._committed[fid], T, p.revise_trans_m, p.revise_rot_deg):
                self._committed[fid] = T.copy()
                out.append((fid, T))
        return sorted(out, key=lambda r: r[0])

    def summary(self) -> dict:
        """Counts of the run so far: keyframes, loop closures, optimisations, refinements, lost and relocalised
        frames, the keyframe store (:meth:`memory`)."""
        return {"keyframes": len(self.keyframes), "keyframe_ids": [k.frame_id for k in self.keyframes],
                "loop_closures": [list(x) for x in self.loops], "optimisations": self.optimisations,
                "loops_skipped": self.loops_skipped, "heading": self.heading, "level": self.level,
                "refinements": self.refinements,
                "keyframe_store": self.memory(),
                "lost_frames": list(self.lost), "relocalised_frames": list(self.relocalised),
                "params": dataclasses.asdict(self.params), "stride": self.stride}
