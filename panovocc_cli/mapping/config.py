"""The configs of ``panovocc map`` and ``revise`` and of the :class:`~.mapper.Mapper`, in a module that
imports nothing heavy.

``panovocc --help`` builds every command's options from the stage configs (cli/options.py), so the
modules holding them import only the standard library, numpy, numpy-free parameter modules
(:mod:`.params`, :mod:`panovocc_cli.semantics.params`, :mod:`panovocc_cli.semantics.gsc`) and
:mod:`panovocc_cli.config` -- never numba. A map folder's ``config.json`` is read by one parser
(:func:`_read_sections`), whether it was written by a map run (:class:`MapConfig`) or by
:meth:`Mapper.save <.mapper.Mapper.save>` (:class:`MapperConfig`, the mapper's sections only).
"""

from __future__ import annotations

import json
import math

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import DEFAULT_SEED, MAX_SEED, MAX_STRIDE, option, typed_from_json
from ..errors import PanovoccError
from ..evaluation.trajectory import PLACEMENTS, POSE_FIT
from ..geometry.lattice import key_reach, local_origin
from ..semantics.gsc import GSCParams
from ..semantics.params import EvidenceWeights
from ..semantics.registry import SEGMENTER_AUTO, SEGMENTER_NONE
from .ablation import AblationParams
from .params import KERNELS, RADIAL, RULES, GeometryParams, OccupancyParams

FORMAT_VERSION = 4  # of a map folder; 2: semantic section (a version-1 config is a geometry-only map); 3: footprint-
# fitted surfels, N = frames with a measurement, occupancy rule; 4: semantic channels from kept observations, in
# integer steps (mapping/contributors.py)
SEMANTIC_FORMAT = 4  # the first format whose semantic channels this panovocc reads

POSES_SLAM = "slam"  # --poses slam: poses estimated online by a front end the caller passes (slam/run.py)
FIRST_POSE_REFERENCE = "reference"  # --first-pose reference: the reference trajectory's pose of the first frame
RIGID = ("se3", POSE_FIT)  # the --poses-align modes that move a trajectory rigidly (--poses slam takes these)
SLAM_PRESETS = ("default", "building")  # --slam-preset: the names of slam.tracker.PRESETS (tested equal)
PLY_COLORS = ("class", "rgb", "height")


def mapper_gsc_params() -> GSCParams:
    """GSC parameters of ``panovocc map``: the library defaults with stronger spatial regularisation.

    ``lambda_s = 8`` and ``iterations = 20`` (library: 1 and 10), tuned on the synthetic scene of seed 0
    and checked on seed 1 (docs/mapping.md, "Semantic memory"). ``s_g = 0.5`` is kept: the mapper's
    signed score g is in per-frame support units (about 0.1..1 on surfaces), the scale GSC assumes,
    and the result is flat in s_g over 0.25..2.
    """
    return GSCParams(lambda_s=8.0, iterations=20)


@dataclass
class SemanticParams:
    """Semantic part of a map's configuration (saved in ``OUT/config.json``).

    segmenter : ``auto`` (simulated when the sequence has labels, else an error), ``simulated``,
        ``precomputed:DIR``, ``clip[...]`` (:mod:`semantics.clip`) or ``none`` (geometry only: every occupied
        voxel 254)
    vocab : vocabulary spec (``eval8,open4``, ``a,b,c``; None = eval8 + open4) before :func:`resolve`,
        the list of canonical names after it
    noise, seed : the simulated segmenter's noise level (0 = exact) and seed
    use_gsc : False = the ``--no-gsc`` ablation (raw argmax + the same nearest-evidence transfer)
    ply_color : colours of map.ply: ``class`` (class colours, grey for 254), ``rgb`` (mean pixel colour),
        ``height``
    features, feature_dim : keep the segmenter's per-pixel embeddings fused per voxel (channel ``Z``, D =
        ``feature_dim`` after the map's fixed projection: :mod:`panovocc_cli.semantics.features`)
    """

    segmenter: str = option(SEGMENTER_AUTO, show_default=False,
                            help="Semantic segmenter: simulated (from SEQ/semantic/ labels) | precomputed:DIR | "
                                 "clip[:MODEL@WEIGHTS | :FOLDER][,options] (dense CLIP, docs/semantics.md) | none "
                                 "(geometry only, occupied voxels 254). Default: simulated when SEQ has labels, else "
                                 "you must choose.")
    vocab: object = option(None, cli_type=str, help="Vocabulary chosen at run time: class names and sets, comma- or "
                                                    "+-separated (eval8, open4, eval12, e.g. 'eval8,pillow'); "
                                                    "default eval8,open4.")
    noise: float = option(1.0, min=0, help="Simulated segmenter noise level (dimensionless; 1 = default realistic "
                                           "errors, 0 = exact).")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Seed of the simulated segmenter's noise.")
    use_gsc: bool = option(True, flag="--no-gsc", negate=True, help="Ablation: raw argmax of the fused evidence, no GSC.")
    ply_color: str = option("class", choices=PLY_COLORS, help="map.ply colours: class (class colours, grey = no class) "
                                                              "| rgb (mean pixel colour) | height.")
    features: bool = option(False, help="Also keep language-aligned features per voxel (the segmenter's "
                                        "embeddings, projected to --feature-dim), so that query and relabel reach "
                                        "any words after mapping (docs/semantics.md, \"Feature memory\").")
    feature_dim: int = option(64, min=1, max=1024, help="Dimension D of the feature memory (4 D bytes per voxel "
                                                        "with semantic evidence).")
    gsc: GSCParams = field(default_factory=mapper_gsc_params)
    weights: EvidenceWeights = field(default_factory=EvidenceWeights)

    @property
    def enabled(self) -> bool:
        return self.segmenter != SEGMENTER_NONE

    @classmethod
    def from_json(cls, d: dict | None) -> "SemanticParams":
        """Inverse of ``dataclasses.asdict``; a config without a semantic section is a geometry-only map."""
        if d is None:
            return cls(segmenter=SEGMENTER_NONE, vocab=[])
        d = dict(d)
        gsc = dataclasses.replace(mapper_gsc_params(), **d.pop("gsc", {}))
        weights = EvidenceWeights(**d.pop("weights", {}))
        return cls(gsc=gsc, weights=weights, **d)


def check_key_reach(g: GeometryParams) -> None:
    """Refuse a voxel size whose keys cannot hold one frame's reach (``--max-range``) around the origin."""
    if key_reach(g.voxel_size) <= g.max_range:
        raise PanovoccError(f"--voxel-size {g.voxel_size:g} m is too small: voxel keys reach "
                            f"{key_reach(g.voxel_size):.3g} m from the map's origin, less than --max-range "
                            f"{g.max_range:g} m")


MERGED_FROM = "merged_from"  # config.json of a merge of maps of several sequences: those maps (mapping/merge.py)


def several_sequences(raw: dict) -> bool:
    """Whether a map folder's ``config.json`` (parsed) is a merge of maps of several sequences, or of maps
    renumbered (``merge --renumber``): its frame ids no longer name one sequence's frames, so it cannot be
    revised or resumed."""
    sources = raw.get(MERGED_FROM) or []
    return len({m["seq"] for m in sources}) > 1 or any(int(m.get("first_id", 0)) != 0 for m in sources)


def parse_frames(text) -> str:
    """``--frames`` as typed: ``A:B`` (frames A..B-1 of the sequence; ``A:`` to its end, ``:B`` from 0), or
    several such ranges separated by commas; returned with spaces removed. One line naming --frames
    otherwise (the sequence's length is checked by :func:`frame_ids`)."""
    spec = str(text).replace(" ", "")
    for part in spec.split(","):
        a, sep, b = part.partition(":")
        if sep != ":" or not all(x == "" or x.isdigit() for x in (a, b)) or (a == b == ""):
            raise PanovoccError(f"--frames must be A:B (frame indices, B excluded; A: to the end), or ranges "
                                f"A:B,C:D, got {text!r}")
    return spec


def frame_ids(spec: str | None, n: int) -> np.ndarray:
    """The sequence indices (ascending, distinct) a ``--frames`` spec names in a sequence of ``n`` frames
    (None: all of them). A range that is empty, reversed, past the sequence's end, or overlapping another
    is refused with one line naming --frames."""
    if spec is None:
        return np.arange(n, dtype=np.int64)
    spec = parse_frames(spec)
    ids: list = []
    for part in spec.split(","):
        a, _, b = part.partition(":")
        lo, hi = int(a) if a else 0, int(b) if b else n
        if not lo < hi or hi > n:
            raise PanovoccError(f"--frames {part}: the sequence has frames 0:{n}; a range A:B needs "
                                f"0 <= A < B <= {n}")
        ids.extend(range(lo, hi))
    out = np.asarray(sorted(ids), np.int64)
    if len(np.unique(out)) != len(out):
        raise PanovoccError(f"--frames {spec}: its ranges overlap")
    return out


def parse_origin(text) -> list[float]:
    """``X,Y,Z`` (metres) -> [x, y, z]; one line naming --origin otherwise."""
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise PanovoccError(f"--origin must be three finite numbers X,Y,Z in metres, got {text!r}")
    return vals


def parse_slam_params(text) -> str:
    """``--slam-params`` as typed: a JSON object of front-end parameters (``SlamParams`` fields, whose names
    and types :func:`panovocc_cli.slam.run.slam_params` checks); returned as compact JSON with sorted keys.
    One line naming --slam-params otherwise."""
    try:
        d = json.loads(str(text))
    except ValueError:
        d = None
    if not isinstance(d, dict) or not d or not all(isinstance(v, (bool, int, float, str)) for v in d.values()):
        raise PanovoccError("--slam-params must be a non-empty JSON object of front-end parameters (SlamParams fields, "
                            f"docs/slam.md), e.g. '{{\"refine_radius_m\": 1.0}}', got {text!r}")
    return json.dumps(d, sort_keys=True, separators=(",", ":"))


@dataclass
class MapConfig:
    """Everything ``panovocc map`` needs; saved resolved as ``OUT/config.json``.

    The run's own fields (``seq``, ``out``, ``poses``, ``checkpoint_every``, ``stride`` and
    ``semantic_stride`` as requested, the
    segmenter spec, noise and seed and ``ply_color`` in ``semantic``) sit beside the mapper's parameters
    (``geometry``, ``occupancy``, the rest of ``semantic``): :meth:`mapper_config`.
    """

    seq: str = option(cli_type=Path, parse=str, argument=True, metavar="SEQ", cli_optional=True,
                      help="Sequence folder (CONVENTIONS.md layout); omit with --resume.")
    out: str = option(cli_type=Path, parse=str, argument=True, metavar="OUT", cli_optional=True,
                      help="Output folder for the memory, prediction.npz and map.ply.")
    poses: str | None = option(None, cli_type=Path, parse=str,
                               help="Pose file (NICE-SLAM, or TUM with timestamps matched to frame indices), or "
                                    "'slam' to estimate the poses online (SEQ/poses.txt is then never read); "
                                    "default SEQ/poses.txt.")
    poses_align: str = option("none", choices=PLACEMENTS,
                              help="Align the --poses file to a reference trajectory first: none | se3 (Umeyama, "
                                   "positions) | se3-pose (whole poses: orientations too, each weighted by its "
                                   "scatter; for a reference with per-frame noise) | sim3. With --poses slam: se3 "
                                   "or se3-pose fits the final poses to the reference and moves every frame there "
                                   "(the map in the reference's world).")
    poses_reference: str | None = option(None, cli_type=Path, parse=str,
                                         help="Reference trajectory of --poses-align and of --first-pose reference; "
                                              "default SEQ/poses.txt.")
    first_pose: str | None = option(None, cli_type=Path, parse=str, metavar="FILE|reference",
                                    help="With --poses slam: the first frame's pose T_world_cam, which the SLAM world "
                                         "starts from (a file: a 4x4 matrix, NICE-SLAM or TUM; 'reference': "
                                         "--poses-reference's pose of that frame). Default: the first frame, "
                                         "levelled, at the origin.")
    checkpoint_every: int = option(25, min=0, help="Checkpoint the memory every K frames (0 = only at the end).")
    revise_per_frame: int = option(0, min=0, metavar="K",
                                   help="With --poses slam: at most K map revisions a frame after a pose-graph "
                                        "optimisation, the largest corrections first, the rest with later frames "
                                        "(0 = every one at once); the final refinement revises all that are left.")
    heading_prior: bool = option(False, help="With --poses slam: the final refinement holds each keyframe's heading to "
                                             "the walls it sees (perpendicular walls, modulo 90 deg, as the first "
                                             "keyframes see them): for buildings, whose stairs turn a floor a little.")
    slam_preset: str = option("default", choices=SLAM_PRESETS,
                              help="With --poses slam: a named set of front-end parameters: default | building "
                                   "(a multi-storey walk with long corridors: the final refinement's pairs within "
                                   "1 m, each keyframe's heading held to its walls and its tilt to its floors; "
                                   "docs/slam.md). --slam-params and --heading-prior apply on top.")
    slam_params: str | None = option(None, cli_type=str, parse=parse_slam_params, metavar="JSON", show_default=False,
                                     help="With --poses slam: front-end parameters other than the defaults, a JSON "
                                          "object of SlamParams fields (docs/slam.md), e.g. "
                                          "'{\"refine_radius_m\": 1.0}' for a building's long corridors.")
    # a range of the sequence's frames (ids stay the sequence's indices); None = every frame
    frames: str | None = option(None, cli_type=str, parse=parse_frames, metavar="A:B", show_default=False,
                                help="Map only frames A..B-1 of the sequence (A: to its end; A:B,C:D several "
                                     "ranges); frame ids stay the sequence's indices, the origin stays the "
                                     "sequence's first frame's, so maps of pieces merge (panovocc merge).")
    frame_times: str | None = option(None, cli_type=Path, parse=str,
                                     help="Write a CSV of every frame's cost (frame, wall and process CPU "
                                          "seconds since the first frame, update ms, checkpoint 0/1, resident "
                                          "MB) to this file.")
    # the map's local origin, metres, world (voxel keys are relative to it); None = the first frame's voxel
    origin: list | None = option(None, cli_type=str, parse=lambda t: parse_origin(t),
                                 help="Map origin X,Y,Z in metres (world), snapped to the voxel lattice; voxel keys "
                                      "are relative to it and reach about 84 km at 8 cm. Default: the first "
                                      "frame's position.")
    geometry: GeometryParams = field(default_factory=GeometryParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    # requested stride; 0 = auto (max(1, W // 256)); the resolved one is geometry.stride
    stride: int = option(0, min=0, max=MAX_STRIDE,
                         help="Pixel stride s of the kernel lift; 0 = auto, max(1, W // 256) (4 at 1024).")
    # requested semantic stride; 0 = auto (max(1, W // 512)); the resolved one is semantic.weights.stride
    semantic_stride: int = option(0, min=0, max=MAX_STRIDE,
                                  help="Pixel stride of the semantic measurements (every s-th row and column, "
                                       "each weighing s^2; the segmenter runs at that resolution); 0 = auto, "
                                       "max(1, W // 512) (2 at 1024).")
    # segmenter, vocabulary, GSC; the default "auto" = simulated when the sequence has labels, else none
    semantic: SemanticParams = field(default_factory=SemanticParams)
    # the ablation switches: without RPU, the pose perturbation-and-correction schedule (mapping/ablation.py)
    ablation: AblationParams = field(default_factory=AblationParams)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        if d["frames"] is None:  # a whole-sequence map's config.json as before --frames existed
            del d["frames"]
        if not d["revise_per_frame"]:  # likewise before --revise-per-frame
            del d["revise_per_frame"]
        if not d["heading_prior"]:  # and before --heading-prior
            del d["heading_prior"]
        if d["slam_params"] is None:  # and before --slam-params
            del d["slam_params"]
        if d["slam_preset"] == "default":  # and before --slam-preset
            del d["slam_preset"]
        d["format_version"] = FORMAT_VERSION
        return d

    @classmethod
    def from_json(cls, d: dict, where) -> "MapConfig":
        """From a map run's ``config.json`` (:func:`_read_sections`; the run's fields are required)."""
        g, o, s, origin = _read_sections(d, where)
        try:
            return cls(seq=str(d["seq"]), out=str(d["out"]), poses=d.get("poses"),
                       poses_align=str(d.get("poses_align", "none")), poses_reference=d.get("poses_reference"),
                       first_pose=d.get("first_pose"),
                       checkpoint_every=int(d["checkpoint_every"]), frame_times=d.get("frame_times"),
                       revise_per_frame=int(d.get("revise_per_frame", 0)),
                       heading_prior=bool(d.get("heading_prior", False)),
                       slam_preset=_slam_preset(d.get("slam_preset", "default")),
                       slam_params=None if d.get("slam_params") is None else parse_slam_params(d["slam_params"]),
                       frames=None if d.get("frames") is None else parse_frames(d["frames"]),
                       geometry=g, occupancy=o, origin=origin,
                       stride=int(d.get("stride", 0)), semantic_stride=int(d.get("semantic_stride", 0)),
                       semantic=s, ablation=AblationParams.from_json(d.get("ablation")))
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise PanovoccError(f"not a panovocc map config ({type(e).__name__}: {e})", where) from None

    def reference_path(self) -> Path:
        """The reference trajectory of ``--poses-align`` and ``--first-pose reference``: ``--poses-reference``,
        default SEQ/poses.txt."""
        return Path(self.poses_reference) if self.poses_reference is not None else Path(self.seq) / "poses.txt"

    def mapper_config(self) -> "MapperConfig":
        """The mapper's part of a resolved config (the vocabulary is empty for ``--segmenter none``)."""
        return MapperConfig.of(self.geometry, self.occupancy, self.semantic, self.origin)


def _slam_preset(name) -> str:
    if name not in SLAM_PRESETS:
        raise ValueError(f"slam_preset {name!r} is not one of {', '.join(SLAM_PRESETS)}")
    return str(name)


def _read_sections(d, where) -> tuple[GeometryParams, OccupancyParams, SemanticParams, list | None]:
    """The mapper's sections of a map folder's ``config.json`` (``d``, parsed JSON): geometry, occupancy,
    semantic (absent: a geometry-only map) and the local origin (absent: a map made before local origins,
    keyed relative to the world's). Refuses, naming ``where``, anything but a JSON object of a format
    version this panovocc reads with sections of the right keys and types, and a semantic map older than
    :data:`SEMANTIC_FORMAT`."""
    if not isinstance(d, dict):
        raise PanovoccError("not a panovocc map config (expected a JSON object)", where)
    version = d.get("format_version", 1)
    if type(version) is not int or not 1 <= version <= FORMAT_VERSION:
        raise PanovoccError(f"format_version {version!r}: this panovocc reads map formats 1 to {FORMAT_VERSION} "
                            "(a newer panovocc wrote it, or the file is corrupt)", where)
    try:
        g = typed_from_json(GeometryParams, d["geometry"])
        if "observe_hits" not in d["geometry"]:  # made before O counted N: resume and revise as it was made
            g = dataclasses.replace(g, observe_hits=False)
        if "offsets" not in d["geometry"]:  # made before the surface-offset channel P: resume and revise without it
            g = dataclasses.replace(g, offsets=False)
        o = typed_from_json(OccupancyParams, d["occupancy"])
        if "spill" not in d["occupancy"]:  # made before the spill thinning: export as it was made
            o = dataclasses.replace(o, spill=0.0)
        if "resolve" not in d["occupancy"]:  # made before the face resolution: export as it was made
            o = dataclasses.replace(o, resolve=False)
        if "resolve_behind" not in d["occupancy"]:  # made before its margin: resolve as it was made
            o = dataclasses.replace(o, resolve_behind=0.0)
        s = SemanticParams.from_json(d.get("semantic"))
        origin = None if d.get("origin") is None else [float(v) for v in d["origin"]]
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise PanovoccError(f"not a panovocc map config ({type(e).__name__}: {e})", where) from None
    if s.enabled and s.vocab and version < SEMANTIC_FORMAT:
        raise PanovoccError(f"a semantic map of format {version}, whose class evidence this panovocc no longer reads "
                            f"(format {SEMANTIC_FORMAT} keeps segmenter observations in integer steps): map the "
                            "sequence again", where)
    return g, o, s, origin


@dataclass
class MapperConfig:
    """Everything the mapper computes with: geometry, occupancy and semantic fusion parameters.

    geometry : GeometryParams (``stride`` is the resolved pixel stride; the map command sets
        ``max(1, W // 256)``, 4 at 1024)
    occupancy : OccupancyParams, the decision rule
    vocab : list of str, the canonical class names of the logits frames carry (C of them); empty =
        geometry only (logits are then ignored and occupied voxels export as 254)
    use_gsc : False = the ``--no-gsc`` ablation (raw argmax + the same nearest-evidence transfer)
    gsc : GSCParams of the labelled export; weights : EvidenceWeights of the semantic evidence
    origin : (3,) float metres, world, on the lattice (a whole number of voxels), or None: the map's local
        origin, which its voxel keys are relative to (``geometry.lattice.local_origin``); None = the
        voxel of the first integrated frame's position
    feature_dim : D of the feature channel ``Z`` (0: none); frames then carry per-pixel ``features``
    """

    geometry: GeometryParams = field(default_factory=GeometryParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    vocab: list = field(default_factory=list)
    use_gsc: bool = True
    gsc: GSCParams = field(default_factory=mapper_gsc_params)
    weights: EvidenceWeights = field(default_factory=EvidenceWeights)
    origin: list | None = None
    feature_dim: int = 0

    @classmethod
    def of(cls, geometry: GeometryParams, occupancy: OccupancyParams, semantic: SemanticParams,
           origin: list | None) -> "MapperConfig":
        """The mapper's config of a map's sections (the vocabulary is empty for ``--segmenter none``)."""
        return cls(geometry=geometry, occupancy=occupancy,
                   vocab=list(semantic.vocab) if semantic.enabled else [], use_gsc=semantic.use_gsc,
                   gsc=semantic.gsc, weights=semantic.weights, origin=None if origin is None else list(origin),
                   feature_dim=int(semantic.feature_dim) if semantic.enabled and semantic.features else 0)

    def check(self) -> "MapperConfig":
        """Validate the parameter ranges; raise :class:`PanovoccError` naming the option."""
        g = self.geometry
        if not (np.isfinite(g.voxel_size) and g.voxel_size > 0):
            raise PanovoccError(f"--voxel-size must be positive, got {g.voxel_size}")
        check_key_reach(g)
        if int(g.stride) < 1:
            raise PanovoccError(f"stride must be >= 1, got {g.stride}")
        if g.kernel not in KERNELS:
            raise PanovoccError(f"--kernel must be psvf or point, got {g.kernel!r}")
        if self.occupancy.resolve and not g.offsets:  # the face resolution reads channel P: record it
            g = self.geometry = dataclasses.replace(g, offsets=True)
        if self.occupancy.rule not in RULES:
            raise PanovoccError(f"--rule must be frequency or score, got {self.occupancy.rule!r}")
        if g.radial not in RADIAL:
            raise PanovoccError(f"radial must be fit or model, got {g.radial!r}")
        if not all(isinstance(w, str) and w for w in self.vocab) or len(set(self.vocab)) != len(self.vocab):
            raise PanovoccError(f"vocabulary must be distinct class names, got {self.vocab!r}")
        if self.origin is not None:
            o = np.asarray(self.origin, np.float64)
            if o.shape != (3,) or not np.all(np.isfinite(o)):
                raise PanovoccError(f"--origin must be three finite numbers X,Y,Z (metres), got {self.origin!r}")
            self.origin = [float(x) for x in self.origin_index() * g.voxel_size]  # snapped to the lattice
        return self

    def origin_index(self) -> np.ndarray:
        """The origin's lattice index (3,) int64 (zeros without an origin)."""
        if self.origin is None:
            return np.zeros(3, np.int64)
        h = self.geometry.voxel_size
        o = np.asarray(self.origin, np.float64)
        return local_origin(o + 0.5 * h, h)  # a lattice point (a stored origin) reads back as its own voxel

    def to_json(self) -> dict:
        """The map folder's ``config.json`` sections of the mapper (the map command adds its run fields)."""
        return {"geometry": dataclasses.asdict(self.geometry), "occupancy": dataclasses.asdict(self.occupancy),
                "semantic": {"vocab": list(self.vocab), "use_gsc": self.use_gsc,
                             "gsc": dataclasses.asdict(self.gsc), "weights": dataclasses.asdict(self.weights),
                             "features": bool(self.feature_dim), "feature_dim": int(self.feature_dim or 64)},
                "origin": None if self.origin is None else list(self.origin), "format_version": FORMAT_VERSION}

    @classmethod
    def from_json(cls, d: dict, where=None) -> "MapperConfig":
        """From a map folder's ``config.json`` (a mapper's or a map run's: :func:`_read_sections`; the run's
        own fields are not read)."""
        return cls.of(*_read_sections(d, where)).check()


@dataclass
class ReviseConfig:
    """``panovocc revise``: re-integrate the frames of a finished map whose pose changed.

    out : output folder of a finished ``panovocc map`` run; poses : full pose file (one pose per frame);
    progress : draw a progress bar (``--quiet``: no)
    """

    out: str = option(cli_type=Path, parse=str, argument=True, metavar="OUT",
                      help="Output folder of a finished `panovocc map` run.")
    poses: str = option(cli_type=Path, parse=str, argument=True, metavar="POSES",
                        help="Full pose file (one pose per frame, NICE-SLAM or TUM form).")
    progress: bool = option(True, flag="--quiet", negate=True, help="No progress bar.")
