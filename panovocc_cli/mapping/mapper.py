"""The streaming mapper: frames from memory in, a semantic occupancy grid out, poses revisable at any time.

::

    from panovocc_cli.mapping import Mapper, MapperConfig, Frame

    mapper = Mapper(MapperConfig(vocab=["wall", "floor"]))
    for frame in frames:                       # Frame(rgb, depth, T_world_cam, camera, logits=...)
        mapper.integrate(frame)
    mapper.revise(3, T_new)                    # frame 3's pose corrected (e.g. by a loop closure)
    grid = mapper.prediction()                 # panovocc_cli.grid.Grid
    mapper.save("out/")                        # memory.npz, deltas/, config.json, poses.txt
    mapper = Mapper.load("out/")

The mapper never opens an input file: a frame's arrays come in a :class:`~panovocc_cli.frame.Frame`, and
a segmenter, if any, runs before (its logits travel in the frame). Each frame's delta is the geometry
contributor's (:func:`.contributors.geometry_delta`: PSVF support, free space) and, when the frame
carries logits and the configuration a vocabulary, the semantic one (:func:`.semantic.semantic_delta`),
kept as two parts over their own voxels (:class:`~.memory.FrameDelta`).
The deltas are kept by the reversible persistent update (:mod:`.rpu`), so the memory is always their exact
integer sum.

Revising a frame recomputes its delta under the new pose from the frame's depth and colours and from
the semantic observation kept with its delta (the segmenter's output reduced once,
:mod:`panovocc_cli.semantics.observation`): no segmenter runs again. Where depth and colours come from is
the caller's choice:

* ``frame_source=None`` (default): ``integrate`` keeps a reference to each Frame's depth and colours (not a
  copy; its logits are dropped). At 1024x512 that is 3.5 MB per frame (depth 2 MB, rgb 1.5 MB): fine for
  a few hundred frames or short windows, not for a 2,000-frame sequence;
* ``frame_source=callable(frame_id) -> Frame``: nothing is kept; ``revise`` asks for the frame again
  (its pose and logits are ignored). The map commands pass a reader of the sequence folder.

Deltas themselves stay in RAM (``folder=None``) or go to ``folder/deltas/`` as they are made (sizes:
docs/mapping.md, "Delta store size").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import PanovoccError
from ..frame import Frame
from ..grid import Grid
from ..io import mapstore
from ..io.poses import write_poses
from ..semantics.evidence import EvidenceWeights
from ..semantics.gsc import GSCParams
from .contributors import geometry_delta
from .export import MapExport, export_memory
from .config import FORMAT_VERSION, SEMANTIC_FORMAT, mapper_gsc_params
from .memory import GEOMETRY_CHANNELS, ChannelSpec, FrameDelta, VoxelMemory
from .params import GeometryParams, OccupancyParams
from .rpu import DeltaStore, ReversibleMemory, has_store
from .semantic import semantic_channels, semantic_delta

# (2: semantic section; a version-1 config is a geometry-only map)
KERNELS = ("psvf", "point")
RULES = ("frequency", "score")
RADIAL = ("fit", "model")


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
    """

    geometry: GeometryParams = field(default_factory=GeometryParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    vocab: list = field(default_factory=list)
    use_gsc: bool = True
    gsc: GSCParams = field(default_factory=mapper_gsc_params)
    weights: EvidenceWeights = field(default_factory=EvidenceWeights)
    origin: list | None = None

    def check(self) -> "MapperConfig":
        """Validate the parameter ranges; raise :class:`PanovoccError` naming the option."""
        g = self.geometry
        if not (np.isfinite(g.voxel_size) and g.voxel_size > 0):
            raise PanovoccError(f"--voxel-size must be positive, got {g.voxel_size}")
        if int(g.stride) < 1:
            raise PanovoccError(f"stride must be >= 1, got {g.stride}")
        if g.kernel not in KERNELS:
            raise PanovoccError(f"--kernel must be psvf or point, got {g.kernel!r}")
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
        from ..geometry.lattice import local_origin

        if self.origin is None:
            return np.zeros(3, np.int64)
        h = self.geometry.voxel_size
        o = np.asarray(self.origin, np.float64)
        return local_origin(o + 0.5 * h, h)  # a lattice point (a stored origin) reads back as its own voxel

    def channels(self) -> tuple[ChannelSpec, ...]:
        """Memory channels: A N F O, then E S rgb_sum normal_sum count with a vocabulary."""
        return GEOMETRY_CHANNELS + (semantic_channels(len(self.vocab)) if self.vocab else ())

    def to_json(self) -> dict:
        """The map folder's ``config.json`` sections of the mapper (the map command adds its run fields)."""
        return {"geometry": dataclasses.asdict(self.geometry), "occupancy": dataclasses.asdict(self.occupancy),
                "semantic": {"vocab": list(self.vocab), "use_gsc": self.use_gsc,
                             "gsc": dataclasses.asdict(self.gsc), "weights": dataclasses.asdict(self.weights)},
                "origin": None if self.origin is None else list(self.origin), "format_version": FORMAT_VERSION}

    @classmethod
    def from_json(cls, d: dict, where=None) -> "MapperConfig":
        """From a map folder's ``config.json`` (a mapper's or a map run's; extra keys are ignored)."""
        try:
            version = int(d.get("format_version", 1))
            if version > FORMAT_VERSION:
                raise PanovoccError(f"format_version {version} is newer than this panovocc reads ({FORMAT_VERSION})",
                                    where)
            g = GeometryParams(**d["geometry"])
            o = OccupancyParams(**d["occupancy"])
            s = d.get("semantic") or {}
            vocab = [] if s.get("segmenter") == "none" else list(s.get("vocab") or [])
            if vocab and version < SEMANTIC_FORMAT:
                raise PanovoccError(f"a semantic map of format {version}, whose class evidence this panovocc no "
                                    f"longer reads (format {SEMANTIC_FORMAT} keeps segmenter observations in integer "
                                    "steps): map the sequence again", where)
            gsc = dataclasses.replace(mapper_gsc_params(), **s.get("gsc", {}))
            weights = EvidenceWeights(**s.get("weights", {}))
            origin = d.get("origin")  # absent: a map made before local origins (keys relative to the world's)
            return cls(geometry=g, occupancy=o, vocab=vocab, use_gsc=bool(s.get("use_gsc", True)), gsc=gsc,
                       weights=weights, origin=None if origin is None else list(origin)).check()
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise PanovoccError(f"not a panovocc map config ({type(e).__name__}: {e})", where) from None


def has_measurement(depth: np.ndarray) -> bool:
    """Whether any pixel has a depth (> 0 metres; 0 = invalid)."""
    return bool(np.any(np.asarray(depth) > 0))


def frame_delta(frame: Frame, config: MapperConfig, rays: np.ndarray | None = None,
                observation=None) -> FrameDelta:
    """One frame's delta: the geometry's part, and the semantics' part when ``config`` has a vocabulary and
    the frame logits or ``observation`` is given (kept apart, each over its own voxels:
    :class:`~.memory.FrameDelta`, which also keeps the observation).

    The semantic part is computed from the frame's :class:`~panovocc_cli.semantics.observation.
    SemanticObservation`: ``observation`` when given (a revision: the one kept with the frame's delta),
    else the observation of ``frame.logits``. A frame without any valid depth (a dropped sensor frame, all
    zero) is an empty observation: an empty delta. ``rays`` : (H, W, 3) float64 unit rays of the frame's
    camera (cached by the caller).
    """
    g = config.geometry
    if not has_measurement(frame.depth):
        return FrameDelta(())
    parts = [geometry_delta(frame.depth, frame.T_world_cam, g)]
    if config.vocab and (observation is not None or frame.logits is not None):
        if observation is None:
            from ..semantics.observation import observe

            logits = np.asarray(frame.logits)
            s = int(config.weights.stride)
            H, W = frame.camera.shape
            if logits.shape[:2] == (H, W) and s > 1:
                logits = logits[::s, ::s]
            observation = observe(logits)
        if rays is None:
            rays = frame.camera.rays()
        parts.append(semantic_delta(frame.depth, frame.rgb, observation, frame.T_world_cam, g.voxel_size,
                                    config.weights, g.min_range, g.max_range, rays))
    return FrameDelta(tuple(parts), observation)


def _check_pose(T, what: str) -> np.ndarray:
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise PanovoccError(f"{what}: T_world_cam must be a finite (4, 4) matrix, got shape {T.shape}")
    return T


class Mapper:
    """One map: integrate frames, revise or remove them, read the grid, save and reload.

    Parameters
    ----------
    config : MapperConfig
    folder : path or None
        Where the per-frame deltas go as they are made (``folder/deltas/``) and where :meth:`save` writes
        by default; None keeps them in RAM until :meth:`save`. A folder that already holds a map is
        refused (reopen it with :meth:`load`).
    frame_source : callable ``frame_id -> Frame`` or None
        Where :meth:`revise` gets a frame's data again; None keeps each integrated Frame (module docstring).
        A public attribute: it may be set after :meth:`load`.
    """

    def __init__(self, config: MapperConfig, *, folder: str | Path | None = None,
                 frame_source: Callable[[int], Frame] | None = None, _rpu: ReversibleMemory | None = None):
        self.config = config.check()
        if _rpu is None:
            if folder is not None and has_store(folder):
                raise PanovoccError("already holds a map (reopen it with Mapper.load)", folder)
            _rpu = ReversibleMemory(VoxelMemory(config.geometry.voxel_size, config.channels()), DeltaStore(folder))
        self._rpu = _rpu
        if self.config.origin is None and len(_rpu.store):  # a map made before local origins: the world's
            self.config.origin = [0.0, 0.0, 0.0]
        self.frame_source = frame_source
        self._frames: dict[int, Frame] = {}
        self._rays: dict = {}
        ids = self._rpu.store.ids()
        self._next_id = ids[-1] + 1 if ids else 0
        self.empty_frames: list[int] = []  # ids integrated here whose delta was empty (no valid depth)

    # -- state -----------------------------------------------------------------------------------
    @property
    def memory(self) -> VoxelMemory:
        """The voxel memory (the exact sum of the kept deltas)."""
        return self._rpu.memory

    @property
    def frame_ids(self) -> list[int]:
        """Ids of the frames the map holds, ascending."""
        return self._rpu.store.ids()

    @property
    def folder(self) -> Path | None:
        """The folder the deltas live in (None: in RAM)."""
        return self._rpu.store.folder

    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) float64 T_world_cam the frame's kept delta was computed under."""
        if frame_id not in self._rpu.store:
            raise PanovoccError(f"frame {frame_id} is not in the map")
        return self._rpu.store.poses[int(frame_id)].copy()

    def __len__(self) -> int:
        return len(self._rpu.store)

    # -- frames ----------------------------------------------------------------------------------
    def _local(self, frame: Frame) -> Frame:
        """The frame with its pose in the map's local frame (origin subtracted), range-checked; the first
        frame of a map without an origin sets it."""
        from ..geometry.lattice import key_reach, local_origin

        T = np.asarray(frame.T_world_cam, np.float64)
        h = self.config.geometry.voxel_size
        if self.config.origin is None:
            self.config.origin = [float(x) for x in local_origin(T[:3, 3], h) * h]
        t = T[:3, 3] - self.config.origin_index() * h
        reach = key_reach(h) - self.config.geometry.max_range
        if not np.all(np.abs(t) < reach):
            raise PanovoccError(f"frame {frame.index}: camera at {np.round(T[:3, 3], 3).tolist()} m is "
                                f"{float(np.abs(t).max()):.0f} m from the map's origin {self.config.origin}; voxel "
                                f"keys reach {reach:.0f} m at {h} m voxels less --max-range (use --origin nearer, "
                                "or a larger --voxel-size)")
        if not np.any(t != T[:3, 3]):
            return frame
        L = T.copy()
        L[:3, 3] = t
        return dataclasses.replace(frame, T_world_cam=L)

    def _delta(self, frame: Frame, observation=None) -> FrameDelta:
        frame.check()
        frame = self._local(frame)
        C = len(self.config.vocab)
        if C and observation is None and frame.logits is not None and np.shape(frame.logits)[2] != C:
            raise PanovoccError(f"frame {frame.index}: logits have {np.shape(frame.logits)[2]} classes, the "
                                f"vocabulary {C}")
        if C and observation is not None and observation.n_classes != C:
            raise PanovoccError(f"frame {frame.index}: its kept semantic observation has {observation.n_classes} "
                                f"classes, the vocabulary {C}")
        rays = None
        if C and (frame.logits is not None or observation is not None):
            rays = self._rays.get(frame.camera)
            if rays is None:
                rays = self._rays[frame.camera] = frame.camera.rays()
        return frame_delta(frame, self.config, rays, observation)

    def integrate(self, frame: Frame) -> int:
        """Add a frame; returns its id (``frame.index`` when set, else the next unused id).

        A frame that touches no voxel (no valid depth pixel, e.g. a dropped sensor frame, or none within
        range) is integrated as an empty observation: it changes nothing and its id is listed in
        :attr:`empty_frames`.
        """
        fid = int(frame.index) if frame.index is not None else self._next_id
        if fid < 0:
            raise PanovoccError(f"frame id must be >= 0, got {fid}")
        if fid in self._rpu.store:
            raise PanovoccError(f"frame {fid} is already in the map (revise or remove it)")
        delta = self._delta(frame)
        self._rpu.keep(fid, delta, frame.T_world_cam)
        if len(delta) == 0:
            self.empty_frames.append(fid)
        if self.frame_source is None:  # the logits are not needed again: the delta keeps their observation
            self._frames[fid] = dataclasses.replace(frame, logits=None) if delta.observation is not None else frame
        self._next_id = max(self._next_id, fid + 1)
        return fid

    def revise(self, frame_id: int, T_world_cam: np.ndarray, frame: Frame | None = None) -> bool:
        """Move frame ``frame_id`` to pose ``T_world_cam`` (4, 4): its delta is recomputed and swapped in.

        Returns False (nothing done) when the pose is unchanged. Exact: the memory then equals that of a
        map that had integrated the frame under this pose from the start. The frame's depth and colours
        come from the kept Frame or ``frame_source``; its semantics from the observation kept with its
        delta, so no segmenter runs (a ``frame_source`` need not segment; logits it gives are not used
        when an observation is kept). ``frame``: the frame's data when the caller already has it (read
        ahead: ``panovocc revise``); its pose and logits are ignored.
        """
        fid = int(frame_id)
        T = _check_pose(T_world_cam, f"frame {fid}")
        if np.array_equal(T, self.pose(fid)):
            return False
        if frame is None:
            frame = self._frames.get(fid)
        if frame is None:
            if self.frame_source is None:
                raise PanovoccError(f"frame {fid}: its data is not kept (a loaded map needs a frame_source to revise)")
            frame = self.frame_source(fid)
        old = self._rpu.store.get(fid)
        frame = dataclasses.replace(frame, T_world_cam=T)
        self._rpu.revise(fid, self._delta(frame, old.observation), T, old=old)
        if fid in self._frames:
            self._frames[fid] = frame
        return True

    def remove(self, frame_id: int) -> None:
        """Take frame ``frame_id`` out: the memory equals that of a map that never had it."""
        self._rpu.remove(int(frame_id))
        self._frames.pop(int(frame_id), None)
        if int(frame_id) in self.empty_frames:
            self.empty_frames.remove(int(frame_id))

    # -- outputs ---------------------------------------------------------------------------------
    def export(self) -> MapExport:
        """The labelled grid and the occupied voxels (keys, labels, channels) of the current memory."""
        keys, ch = self.memory.nonzero()
        return export_memory(keys, ch, self.config.geometry.voxel_size, self.config.occupancy, self.config.vocab,
                             self.config, origin_index=self.config.origin_index())

    def prediction(self) -> Grid:
        """The semantic occupancy grid: 1..C vocabulary classes (254 occupied without class), 0 free,
        255 unobserved; ``class_names = ["empty"] + vocab``."""
        return self.export().grid

    # -- persistence -----------------------------------------------------------------------------
    def checkpoint(self, *, background: bool = False) -> None:
        """Commit the folder's delta log: what a reopened map holds from now on. Writes one small record
        (no memory file, no pose file), so its cost does not grow with the map; ``background``: on the
        delta writer thread (:meth:`close` waits for it and re-raises its error)."""
        self._rpu.checkpoint(background)

    def save(self, folder: str | Path | None = None, *, background: bool = False) -> Path:
        """Persist the map into ``folder`` (default: the mapper's own folder) and return it.

        Writes the deltas not yet there, then ``memory.npz`` (the commit point), then ``config.json``
        (unless the folder's config already holds this mapper's parameters, e.g. a map run's) and
        ``poses.txt`` (the kept frames' poses in id order). Deltas kept in RAM move to ``folder``.
        ``background=True``: ``memory.npz`` (of the memory as it is at the call) is written on the delta
        writer thread while the caller goes on (the map command's checkpoints); it is on disk once
        :meth:`close` returns, which re-raises a failed write.
        """
        folder = Path(folder) if folder is not None else self.folder
        if folder is None:
            raise PanovoccError("Mapper.save needs a folder (this mapper keeps its deltas in RAM)")
        self._rpu.save(folder, background)
        cfg_path = folder / mapstore.CONFIG_NAME
        try:
            same = cfg_path.is_file() and MapperConfig.from_json(mapstore.read_map_config(folder)) == self.config
        except PanovoccError:
            same = False
        if not same:
            mapstore.write_map_config(folder, self.config.to_json())
        write_poses(folder / "poses.txt", self._rpu.poses()[1])
        return folder

    @classmethod
    def load(cls, folder: str | Path, frame_source: Callable[[int], Frame] | None = None) -> "Mapper":
        """Reopen a saved map (a :meth:`save` folder or a ``panovocc map`` output). Its deltas stay in
        ``folder``; revising a frame needs ``frame_source``."""
        folder = Path(folder)
        config = MapperConfig.from_json(mapstore.read_map_config(folder), folder / mapstore.CONFIG_NAME)
        rpu = ReversibleMemory.load(folder, config.channels(), config.geometry.voxel_size)
        specs = tuple(rpu.memory.specs)
        if specs != config.channels() or rpu.memory.voxel_size != config.geometry.voxel_size:
            rpu.close()
            raise PanovoccError(f"memory channels {[s.name for s in specs]} (voxel {rpu.memory.voxel_size} m) do not "
                                "match config.json", folder / mapstore.MEMORY_NAME)
        return cls(config, frame_source=frame_source, _rpu=rpu)

    def close(self) -> None:
        """Finish pending delta writes and stop the writer thread (the mapper stays usable)."""
        self._rpu.close()

    def __enter__(self) -> "Mapper":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
