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
carries logits and the configuration a vocabulary, the semantic one (:func:`.contributors.semantic_delta`),
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
import functools
import threading
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..errors import PanovoccError
from ..frame import Frame
from ..geometry.poses import check_rigid
from ..grid import Grid
from ..io import mapstore
from ..io.poses import write_poses
from .config import MapperConfig
from .contributors import geometry_parts, semantic_channels, semantic_delta
from .export import MapExport, OccupiedChannels, export_memory
from .memory import GEOMETRY_CHANNELS, GEOMETRY_NAMES, OFFSET_CHANNEL, ChannelSpec, FrameDelta, NonzeroChannels, VoxelMemory
from .rpu import DeltaStore, ReversibleMemory, has_store


def memory_channels(config: MapperConfig) -> tuple[ChannelSpec, ...]:
    """The memory channels of a mapper: A N F O, P (surface offsets, ``geometry.offsets``), then E S rgb_sum
    normal_sum count with a vocabulary (and Z with features)."""
    return (GEOMETRY_CHANNELS + ((OFFSET_CHANNEL,) if config.geometry.offsets else ())
            + (semantic_channels(len(config.vocab), config.feature_dim) if config.vocab else ()))


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
    parts = list(geometry_parts(frame.depth, frame.T_world_cam, g))
    if config.vocab and (observation is not None or frame.logits is not None):
        if observation is None:
            observation = frame_observation(frame, config)
        elif config.feature_dim and observation.features is None:
            raise PanovoccError(f"frame {frame.index}: its kept semantic observation has no features, the map keeps "
                                "them (--features)")
        if rays is None:
            rays = frame.camera.rays()
        parts.append(semantic_delta(frame.depth, frame.rgb, observation, frame.T_world_cam, g.voxel_size,
                                    config.weights, g.min_range, g.max_range, rays))
    return FrameDelta(tuple(parts), observation)


def frame_observation(frame: Frame, config: MapperConfig):
    """The semantic observation :func:`frame_delta` makes of ``frame.logits`` (and, in a map with features, of
    ``frame.features``): :class:`~panovocc_cli.semantics.observation.SemanticObservation` at the semantic
    stride; None without a vocabulary or logits. It does not depend on the pose."""
    if not config.vocab or frame.logits is None:
        return None
    from ..semantics.observation import observe

    logits = np.asarray(frame.logits)
    s = int(config.weights.stride)
    H, W = frame.camera.shape
    if logits.shape[:2] == (H, W) and s > 1:
        logits = logits[::s, ::s]
    observation = observe(logits)
    if config.feature_dim:
        observation = dataclasses.replace(observation, features=_frame_features(frame, config))
    return observation


def _frame_features(frame: Frame, config: MapperConfig) -> np.ndarray:
    """The frame's per-pixel features at the semantic stride, projected and quantised for the observation
    (int8 (h, w, D): :func:`panovocc_cli.semantics.features.quantize_features`)."""
    from ..semantics.features import quantize_features

    if frame.features is None:
        raise PanovoccError(f"frame {frame.index}: the map keeps features (--features) but the frame carries none "
                            "(a segmenter that gives embeddings: simulated or clip)")
    f = np.asarray(frame.features)
    s = int(config.weights.stride)
    H, W = frame.camera.shape
    if f.shape[:2] == (H, W) and s > 1:
        f = f[::s, ::s]
    if f.shape[:2] != (-(-H // s), -(-W // s)):
        raise PanovoccError(f"frame {frame.index}: features of shape {f.shape}, expected "
                            f"{(-(-H // s), -(-W // s), 'F')} at the semantic stride {s}")
    return quantize_features(f, _projection(f.shape[2], config.feature_dim))


@functools.lru_cache(maxsize=4)
def _projection(source_dim: int, dim: int) -> np.ndarray:
    from ..semantics.features import projection

    return projection(source_dim, dim)


def _locked(method):
    """Run ``method`` holding the mapper's lock (one call that changes or reads the map at a time)."""
    @functools.wraps(method)
    def run(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return run


def _legacy_origin(config: MapperConfig, n_frames: int) -> MapperConfig:
    """A map made before local origins (``origin`` None, frames kept) has the world's: set it to zeros."""
    if config.origin is None and n_frames:
        config.origin = [0.0, 0.0, 0.0]
    return config


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

    Thread safety: one lock (a ``threading.RLock``) is held by every call that changes or reads the map
    (integrate, revise, remove, pose, frame_ids, export, prediction, checkpoint, save, close), so a SLAM
    thread may revise frames while another thread integrates: the calls run one at a time, whole, and the
    memory is the same as if they had been made in that order from one thread. :attr:`memory` is the live
    object: read it only from the thread that changes the map.
    """

    def __init__(self, config: MapperConfig, *, folder: str | Path | None = None,
                 frame_source: Callable[[int], Frame] | None = None, _rpu: ReversibleMemory | None = None):
        self.config = config.check()
        self._lock = threading.RLock()
        if _rpu is None:
            if folder is not None and has_store(folder):
                raise PanovoccError("already holds a map (reopen it with Mapper.load)", folder)
            _rpu = ReversibleMemory(VoxelMemory(config.geometry.voxel_size, memory_channels(config)), DeltaStore(folder))
        self._rpu = _rpu
        _legacy_origin(self.config, len(_rpu.store))
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
        with self._lock:
            return self._rpu.store.ids()

    @property
    def folder(self) -> Path | None:
        """The folder the deltas live in (None: in RAM)."""
        return self._rpu.store.folder

    @_locked
    def pose(self, frame_id: int) -> np.ndarray:
        """(4, 4) float64 T_world_cam the frame's kept delta was computed under."""
        if frame_id not in self._rpu.store:
            raise PanovoccError(f"frame {frame_id} is not in the map")
        return self._rpu.store.poses[int(frame_id)].copy()

    def __len__(self) -> int:
        with self._lock:
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

    def observe(self, frame: Frame):
        """Frame ``frame``'s semantic observation as :meth:`integrate` would make it of its logits
        (:func:`frame_observation`; None without a vocabulary or logits), checked as it checks them: what a
        reading thread hands :meth:`integrate` instead of the logits (the run loop's prefetching, so the
        logits of a frame, C floats a pixel, are freed as soon as it is read). Pure: no state is read but the
        configuration, so it may run beside the mapper's other methods."""
        frame.check()
        self._check_logits(frame)
        return frame_observation(frame, self.config)

    def _check_logits(self, frame: Frame) -> None:
        C = len(self.config.vocab)
        if C and frame.logits is not None and np.shape(frame.logits)[2] != C:
            raise PanovoccError(f"frame {frame.index}: logits have {np.shape(frame.logits)[2]} classes, the "
                                f"vocabulary {C}")

    def _delta(self, frame: Frame, observation=None) -> FrameDelta:
        frame.check()
        frame = self._local(frame)
        C = len(self.config.vocab)
        if observation is None:
            self._check_logits(frame)
        if C and observation is not None and observation.n_classes != C:
            raise PanovoccError(f"frame {frame.index}: its kept semantic observation has {observation.n_classes} "
                                f"classes, the vocabulary {C}")
        rays = None
        if C and (frame.logits is not None or observation is not None):
            rays = self._rays.get(frame.camera)
            if rays is None:
                rays = self._rays[frame.camera] = frame.camera.rays()
        return frame_delta(frame, self.config, rays, observation)

    @_locked
    def integrate(self, frame: Frame, observation=None) -> int:
        """Add a frame; returns its id (``frame.index`` when set, else the next unused id). ``observation``:
        the frame's semantic observation when the caller made it already (:meth:`observe`), used instead of
        ``frame.logits``.

        A frame that touches no voxel (no valid depth pixel, e.g. a dropped sensor frame, or none within
        range) is integrated as an empty observation: it changes nothing and its id is listed in
        :attr:`empty_frames`.
        """
        fid = int(frame.index) if frame.index is not None else self._next_id
        if fid < 0:
            raise PanovoccError(f"frame id must be >= 0, got {fid}")
        if fid in self._rpu.store:
            raise PanovoccError(f"frame {fid} is already in the map (revise or remove it)")
        delta = self._delta(frame, observation)
        self._rpu.keep(fid, delta, frame.T_world_cam)
        if len(delta) == 0:
            self.empty_frames.append(fid)
        if self.frame_source is None:  # the logits are not needed again: the delta keeps their observation
            self._frames[fid] = dataclasses.replace(frame, logits=None, features=None) \
                if delta.observation is not None else frame
        self._next_id = max(self._next_id, fid + 1)
        return fid

    def delta(self, frame: Frame, observation=None) -> FrameDelta:
        """Frame ``frame``'s delta under this map's configuration and origin, neither added nor kept (what
        :meth:`integrate` adds; a shard worker's, :mod:`.shards`). ``observation``: a kept semantic
        observation to use instead of the frame's logits."""
        return self._delta(frame, observation)

    @_locked
    def keep_encoded(self, frame_id: int, payload: bytes, T_world_cam: np.ndarray, empty: bool = False) -> None:
        """Keep frame ``frame_id``'s delta given as its record payload (:func:`.rpu.encode_record`, made by a
        shard worker or read from another map) without adding it to the memory: the caller then adds the
        exact sum of the deltas so kept (:meth:`add_sum`). ``empty``: the delta touches no voxel."""
        fid = int(frame_id)
        self._rpu.keep_encoded(fid, payload, T_world_cam)
        if empty:
            self.empty_frames.append(fid)
        self._next_id = max(self._next_id, fid + 1)

    @_locked
    def record(self, frame_id: int) -> bytes:
        """Frame ``frame_id``'s kept delta as its record payload (:func:`.rpu.encode_record`; a folder's log
        record as it is): what :meth:`keep_encoded` takes."""
        return self._rpu.store.payload(frame_id)

    @_locked
    def observation(self, frame_id: int):
        """The semantic observation kept with frame ``frame_id``'s delta (None: geometry only)."""
        return self._rpu.store.get(frame_id).observation

    @_locked
    def add_sum(self, delta: FrameDelta) -> None:
        """Add to the memory the exact sum of deltas kept by :meth:`keep_encoded` (a partial memory)."""
        self.memory.add(delta, +1)

    @_locked
    def revise(self, frame_id: int, T_world_cam: np.ndarray, frame: Frame | None = None) -> bool:
        """Move frame ``frame_id`` to pose ``T_world_cam`` (4, 4): its delta is recomputed and swapped in.

        Returns False (nothing done) when the pose is unchanged. Exact: the memory then equals that of a
        map that had integrated the frame under this pose from the start. The frame's depth and colours
        come from the kept Frame or ``frame_source``; its semantics from the observation kept with its
        delta, so no segmenter runs (a ``frame_source`` need not segment; logits it gives are not used
        when an observation is kept). ``frame``: the frame's data when the caller already has it (read
        ahead: ``panovocc revise``); its pose and logits are ignored.
        """
        job = self._revision(frame_id, T_world_cam, frame)
        if job is not None:
            self._swap(*job)
        return job is not None

    @_locked
    def revise_many(self, revisions: Iterable[tuple], done: Callable[[int], None] | None = None) -> int:
        """:meth:`revise` of each ``(frame_id, T_world_cam, frame or None)`` in order, frame ``i + 1``'s delta
        computed while frame ``i``'s is swapped into the memory on a second thread (the memory's kernels
        release the GIL; ``panovocc revise``), and frame ``i + 1``'s kept delta read and decoded on a third
        while frame ``i``'s new delta is computed (decompression and the decoding kernels release it too).
        The same calls in the same order as a loop of :meth:`revise`: the same memory, records and failures
        (a frame listed again waits for the swap in progress and reads its kept delta itself, so that the
        delta, which that frame's earlier swap may still be writing, is read by one thread alone).
        ``done(frame_id)`` is called once a frame's swap is made. Returns the number of frames revised."""
        from concurrent.futures import ThreadPoolExecutor

        pending = None  # (frame id, future) of the swap in progress
        swapped: set[int] = set()  # frames whose swap was submitted
        count = 0

        def finish():
            nonlocal pending, count
            fid, fut = pending
            pending = None
            fut.result()  # a refused sum or a failed delta write is raised here, in order
            count += 1
            if done is not None:
                done(fid)

        def kept(fid, T):
            """Frame ``fid``'s kept delta, read ahead; None where :meth:`_revision` reads it itself (a pose
            it would refuse or leave alone, a frame the map lacks: its own checks then fail in order)."""
            try:  # the store's poses, not self.pose: that takes the lock the calling thread holds
                if fid not in self._rpu.store or np.array_equal(np.asarray(T, np.float64), self._rpu.store.poses[fid]):
                    return None
                return self._rpu.store.get(fid)
            except Exception:  # noqa: BLE001 - read again, in order, by _revision
                return None

        pool = None  # started by the first frame whose pose changed
        reader = None  # started by the first kept delta read ahead
        try:
            items = iter(revisions)
            item = next(items, None)
            ahead = None  # future of ``item``'s kept delta, when it is read ahead
            while item is not None:
                fid, T, frame = item
                fid = int(fid)
                old, ahead = ahead, None
                item = next(items, None)
                if item is not None and int(item[0]) not in swapped and int(item[0]) != fid:
                    reader = reader or ThreadPoolExecutor(max_workers=1, thread_name_prefix="revise-read")
                    ahead = reader.submit(kept, int(item[0]), item[1])
                if pending is not None and fid in swapped:
                    finish()
                try:
                    job = self._revision(fid, T, frame, old)
                except BaseException:
                    if pending is not None:
                        finish()  # the earlier frame's failure first, as a loop of revise would raise it
                    raise
                if pending is not None:
                    finish()
                if job is not None:
                    pool = pool or ThreadPoolExecutor(max_workers=1, thread_name_prefix="revise")
                    pending = (job[0], pool.submit(self._swap, *job))
                    swapped.add(job[0])
            if pending is not None:
                finish()
        finally:
            if reader is not None:
                reader.shutdown(wait=True)
            if pool is not None:
                pool.shutdown(wait=True)  # a failure in the caller's thread waits for the swap in progress
        return count

    def _revision(self, frame_id: int, T_world_cam: np.ndarray, frame: Frame | None, ahead=None):
        """What revising frame ``frame_id`` swaps in: (id, new delta, pose, kept delta, frame), or None when
        the pose is unchanged. Reads the map's state only through the delta store (not the memory).
        ``ahead``: a future of the frame's kept delta read by :meth:`revise_many` (None or its result None:
        read here)."""
        fid = int(frame_id)
        T = check_rigid(T_world_cam, f"frame {fid}: T_world_cam")
        if np.array_equal(T, self.pose(fid)):
            return None
        if frame is None:
            frame = self._frames.get(fid)
        if frame is None:
            if self.frame_source is None:
                raise PanovoccError(f"frame {fid}: its data is not kept (a loaded map needs a frame_source to revise)")
            frame = self.frame_source(fid)
        old = ahead.result() if ahead is not None else None
        if old is None:
            old = self._rpu.store.get(fid)
        frame = dataclasses.replace(frame, T_world_cam=T)
        return fid, self._delta(frame, old.observation), T, old, frame

    def _swap(self, fid: int, delta: FrameDelta, T: np.ndarray, old: FrameDelta, frame: Frame) -> None:
        self._rpu.revise(fid, delta, T, old=old)
        if fid in self._frames:
            self._frames[fid] = frame

    @_locked
    def remove(self, frame_id: int) -> None:
        """Take frame ``frame_id`` out: the memory equals that of a map that never had it."""
        self._rpu.remove(int(frame_id))
        self._frames.pop(int(frame_id), None)
        if int(frame_id) in self.empty_frames:
            self.empty_frames.remove(int(frame_id))

    # -- outputs ---------------------------------------------------------------------------------
    @_locked
    def export(self, previous: Grid | None = None, changed_keys: np.ndarray | None = None, *,
               changed_blocks: np.ndarray | None = None, block: int | None = None) -> MapExport:
        """The labelled grid and the occupied voxels (keys, labels, channels) of the current memory.
        ``previous``: the grid of an export before the voxels ``changed_keys`` and those of the memory blocks
        ``changed_blocks`` changed (an incremental export, the same result: :func:`.export.export_memory`);
        ``block``: its GSC cube side (the same labels; default :data:`~..semantics.gsc.BLOCK`)."""
        mem = self.memory  # read a slab of the key space at a time (never every non-zero voxel's key at once)
        pieces = (lambda: ((keys, NonzeroChannels(mem, loc), loc) for keys, loc in mem.nonzero_slabs()))
        reader = (lambda loc: OccupiedChannels(NonzeroChannels(mem, loc), np.arange(len(loc))))
        return export_memory(None, None, self.config.geometry.voxel_size, self.config.occupancy, self.config.vocab,
                             self.config, origin_index=self.config.origin_index(), previous=previous,
                             changed_keys=changed_keys, changed_blocks=changed_blocks, pieces=pieces,
                             reader=reader, block=block,
                             lookup=lambda keys, names=GEOMETRY_NAMES: mem.gather(keys, names))  # face neighbours

    def prediction(self) -> Grid:
        """The semantic occupancy grid: 1..C vocabulary classes (254 occupied without class), 0 free,
        255 unobserved; ``class_names = ["empty"] + vocab``."""
        return self.export().grid

    # -- persistence -----------------------------------------------------------------------------
    @_locked
    def checkpoint(self, *, background: bool = False) -> None:
        """Commit the folder's delta log: what a reopened map holds from now on. Writes one small record
        (no memory file, no pose file), so its cost does not grow with the map; ``background``: on the
        delta writer thread (:meth:`close` waits for it and re-raises its error)."""
        self._rpu.checkpoint(background)

    @_locked
    def compact(self) -> tuple[int, int]:
        """Rewrite the folder's delta log so it holds only the kept deltas (a revised frame's earlier records
        and a removed frame's are dropped; the memory does not change); the log's bytes before and after.
        Checkpoints and saves compact on their own once the dead records pass half the live ones
        (:meth:`.rpu.DeltaStore.compaction_victims`)."""
        return self._rpu.compact()

    @_locked
    def save(self, folder: str | Path | None = None, *, background: bool | str = False) -> Path:
        """Persist the map into ``folder`` (default: the mapper's own folder) and return it.

        Writes the deltas not yet there, then ``memory.npz`` (the commit point), then ``config.json``
        (unless the folder's config already holds this mapper's parameters, e.g. a map run's; a config.json
        that cannot be read or holds other parameters is refused before anything is written) and
        ``poses.txt`` (the kept frames' poses in id order). Deltas kept in RAM move to ``folder``.
        ``background=True``: ``memory.npz`` (of the memory as it is at the call), the commit and then
        ``poses.txt`` are written on the delta writer thread while the caller goes on (``map`` writes its
        grid and PLY meanwhile); they are on disk once :meth:`close` returns, which re-raises
        a failed write (poses.txt is then left as it was). ``background=FROZEN`` (:data:`.rpu.FROZEN`): the
        same, but ``memory.npz`` is streamed from the memory itself on the writer thread, without the copy
        ``background=True`` takes: the caller must not change the map until :meth:`close` returns (reading
        it is fine: ``revise`` exports it meanwhile).
        """
        folder = Path(folder) if folder is not None else self.folder
        if folder is None:
            raise PanovoccError("Mapper.save needs a folder (this mapper keeps its deltas in RAM)")
        write_config = not self._holds_my_config(folder)  # refuses before anything is written
        poses = self._rpu.poses()[1]
        self._rpu.save(folder, background, after=lambda: write_poses(folder / "poses.txt", poses))
        if write_config:
            mapstore.write_map_config(folder, self.config.to_json())
        return folder

    def _holds_my_config(self, folder: Path) -> bool:
        """Whether ``folder/config.json`` holds this mapper's parameters (a map run's, or an earlier save's):
        True; no config.json: False. One that cannot be read, or holds other parameters, is never overwritten:
        :class:`PanovoccError`."""
        path = folder / mapstore.CONFIG_NAME
        if not (path.exists() or path.is_symlink()):
            return False
        try:
            theirs = MapperConfig.from_json(mapstore.read_map_config(folder), path)
        except PanovoccError as e:
            raise PanovoccError(f"{e} -- Mapper.save does not overwrite a config.json it cannot read; save to "
                                "another folder") from None
        if _legacy_origin(theirs, len(self)) != self.config:
            raise PanovoccError("holds another map's parameters; Mapper.save does not overwrite it (save to "
                                "another folder)", path)
        return True

    @classmethod
    def load(cls, folder: str | Path, frame_source: Callable[[int], Frame] | None = None, *,
             roll_back: bool = False) -> "Mapper":
        """Reopen a saved map (a :meth:`save` folder or a ``panovocc map`` output). Its deltas stay in
        ``folder``; revising a frame needs ``frame_source``. ``roll_back``: a delta log truncated below a
        commit is rolled back to the last commit it reaches (``map --resume``: the map then holds fewer
        frames, mapped again by the caller); else refused."""
        folder = Path(folder)
        config = MapperConfig.from_json(mapstore.read_map_config(folder), folder / mapstore.CONFIG_NAME)
        rpu = ReversibleMemory.load(folder, memory_channels(config), config.geometry.voxel_size, roll_back)
        specs = tuple(rpu.memory.specs)
        if specs != memory_channels(config) or rpu.memory.voxel_size != config.geometry.voxel_size:
            rpu.close()
            raise PanovoccError(f"memory channels {[s.name for s in specs]} (voxel {rpu.memory.voxel_size} m) do not "
                                "match config.json", folder / mapstore.MEMORY_NAME)
        return cls(config, frame_source=frame_source, _rpu=rpu)

    @_locked
    def flush(self) -> None:
        """Wait for the delta record being written. A failed write is undone in the memory and raised here, as
        the next call that changes or saves the map would (``revise`` times its revisions up to their last
        record on disk)."""
        self._rpu._flush()

    @_locked
    def close(self) -> None:
        """Finish pending delta writes and stop the writer thread (the mapper stays usable)."""
        self._rpu.close()

    def __enter__(self) -> "Mapper":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
