"""The methods registry: every row a benchmark table can hold, and what each needs from this build.

A method is a way to turn a scene's rendered sequence into a ``prediction.npz``:

* ``runner="map"``: ``panovocc map`` (:func:`panovocc_cli.mapping.pipeline.run_map`) with a variant of its
  options (``kernel``, ``use_gsc``, ``segmenter``, ``noise``, ``poses``);
* ``runner="baseline"``: ``panovocc baselines run NAME`` (the baselines package).

``groups`` names the tables a method appears in (``main``, ``ablation``, ``upstream``). Methods whose map
options are identical (PanOVOcc, the ablation's full model, the upstream default rows) share one cached
map. A method whose ``requires`` do not all import (:mod:`.available`) is listed in the tables as "not
available in this build"; it is never run and never given a number.

To add a method: one :class:`Method` in :data:`METHODS` (and, for a new runner, one stage function in
:data:`panovocc_cli.benchmark.tasks.STAGES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .available import select_named, unavailable_reason

GROUPS = ("main", "ablation", "upstream")
POSE_SOURCES = ("default", "true", "slam", "drift")

# The map options a variant may set, with PanOVOcc's defaults (the ``panovocc map`` defaults).
MAP_DEFAULTS: dict[str, object] = {"kernel": "psvf", "use_gsc": True, "rpu": True, "segmenter": "simulated",
                                   "noise": 1.0, "poses": "default"}


@dataclass(frozen=True)
class Method:
    """One registry entry.

    name : registry key (``--methods``); label : row label in the tables
    groups : tables it appears in; runner : ``map`` or ``baseline``
    options : for ``map``, the options that differ from :data:`MAP_DEFAULTS`; for ``baseline``, ``{"name": ...}``
    requires : requirements checked by import (:mod:`.available`)
    components : for the ablation table: which of PSVF, GSC, RPU the variant keeps
    note : one line on what the variant is
    """

    name: str
    label: str
    groups: tuple[str, ...]
    runner: str = "map"
    options: dict = field(default_factory=dict)
    requires: tuple[str, ...] = ()
    components: tuple[str, ...] = ("PSVF", "GSC", "RPU")
    note: str = ""

    def map_options(self) -> dict:
        """The full map option set of a ``map`` method (defaults overlaid with its own)."""
        if self.runner != "map":
            raise ValueError(f"{self.name} is not a map variant")
        bad = set(self.options) - set(MAP_DEFAULTS)
        if bad:
            raise ValueError(f"{self.name}: unknown map options {sorted(bad)}")
        return {**MAP_DEFAULTS, **self.options}

    def unavailable(self) -> str | None:
        """None when this build can run the method, else "not available in this build (needs ...)"."""
        return unavailable_reason(self.requires)

    def __hash__(self) -> int:  # options is a dict: hash by name (names are unique in the registry)
        return hash(self.name)


_BASELINE_REQ = ("panovocc_cli.baselines.run:BaselineConfig", "panovocc_cli.baselines.run:run_baseline")

# w/o RPU runs under the perturbation-and-correction schedule of the paper's ablation (mapping/ablation.py,
# docs/baselines.md, whose measured schedule is this one): seeded drift, true poses arriving as corrections every K frames. With RPU the same
# schedule ends exactly at the true-pose map (tested there), which is why the full model's row is PanOVOcc's.
RPU_SCHEDULE = {"rot_deg": 0.5, "trans_m": 0.02, "every": 10}
SLAM_REQ = ("panovocc_cli.slam.run:run_slam_poses", "panovocc_cli.mapping.config:MapConfig.poses_align")
# the upstream "drifting trajectory": odometry-style drift, never corrected (geometry/drift.py)
DRIFT = {"trans_m_per_sqrt_frame": 0.005, "trans_m_per_m": 0.02, "rot_deg_per_frame": 0.2}

METHODS: dict[str, Method] = {m.name: m for m in (
    # --- PanOVOcc itself (main table, the ablation's full model, the upstream default rows) -------------
    Method("panovocc", "PanOVOcc", ("main", "ablation", "upstream"),
           note="panovocc map with its defaults (PSVF kernel, GSC, simulated segmenter at noise 1)"),
    # --- baselines (issue 12: baselines/ + panovocc baselines run) ----------------------------------------
    Method("persp-tsdf", "Perspective TSDF (12 views)", ("main",), runner="baseline",
           options={"name": "persp-tsdf"}, requires=_BASELINE_REQ,
           note="each of the 12 pinhole view streams fused by Open3D TSDF, merged by the paper's rule"),
    Method("single-pano", "Single panorama (no memory)", ("main",), runner="baseline",
           options={"name": "single-pano"}, requires=_BASELINE_REQ,
           note="each panorama mapped alone in a local volume, union of the frames"),
    Method("forward-only", "Forward view only", ("main",), runner="baseline",
           options={"name": "forward-only"}, requires=_BASELINE_REQ,
           note="only the forward middle view of each frame, one perspective stream"),
    # --- component ablation ------------------------------------------------------------------------------
    Method("wo-psvf", "w/o PSVF", ("ablation",), options={"kernel": "point"}, components=("GSC", "RPU"),
           note="map --kernel point: each depth sample votes for the one voxel it falls in"),
    Method("wo-gsc", "w/o GSC", ("ablation",), options={"use_gsc": False}, components=("PSVF", "RPU"),
           note="map --no-gsc: raw argmax of the fused evidence"),
    Method("wo-rpu", "w/o RPU", ("ablation",), options={"rpu": False}, components=("PSVF", "GSC"),
           requires=("panovocc_cli.mapping.ablation:AblationParams.use_rpu",
                     "panovocc_cli.mapping.config:MapConfig.ablation"),
           note="pose corrections arrive but old contributions are not removed (baselines helper's flag)"),
    # --- upstream modules: poses --------------------------------------------------------------------------
    Method("poses-true", "true poses", ("upstream",), options={"poses": "true"},
           note="the renderer's poses"),
    Method("poses-slam", "SLAM front end", ("upstream",), options={"poses": "slam"},
           requires=SLAM_REQ,
           note="the SLAM front end's trajectory (map --poses slam), aligned to the true one (--poses-align se3)"),
    Method("poses-drift", "drifting trajectory", ("upstream",), options={"poses": "drift"},
           requires=("panovocc_cli.geometry.drift:drift_trajectory",),
           note="true poses with a seeded odometry-style drift, never corrected (traj perturb)"),
    # --- upstream modules: segmenter variants ----------------------------------------------------------------
    Method("seg-exact", "segmenter: exact labels", ("upstream",), options={"noise": 0.0},
           note="simulated segmenter at noise 0 (an upper bound: perfect 2D labels)"),
    Method("seg-noisy", "segmenter: noise 2", ("upstream",), options={"noise": 2.0},
           note="simulated segmenter at twice the default noise"),
    Method("seg-overconfident", "segmenter: overconfident", ("upstream",),
           options={"segmenter": "simulated:overconfident"},
           note="simulated segmenter with the overconfident confidence model (T = 0.5)"),
)}


def select_methods(spec: str) -> list[Method]:
    """Methods named by a comma list (``all`` = every method), in registry order."""
    return select_named(METHODS, spec, "method")


def map_cli_flags(opts: dict) -> list[str]:
    """The ``panovocc map`` options that reproduce a resolved map option set (poses handled by the caller)."""
    flags = []
    if opts["kernel"] != MAP_DEFAULTS["kernel"]:
        flags += ["--kernel", str(opts["kernel"])]
    if not opts["use_gsc"]:
        flags.append("--no-gsc")
    if not opts["rpu"]:
        flags.append("--no-rpu")
    if opts["segmenter"] != MAP_DEFAULTS["segmenter"]:
        flags += ["--segmenter", str(opts["segmenter"])]
    if opts["noise"] != MAP_DEFAULTS["noise"]:
        flags += ["--noise", f"{float(opts['noise']):g}"]
    return flags
