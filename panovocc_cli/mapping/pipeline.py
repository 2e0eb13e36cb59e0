"""``run_map`` and ``run_revise``: thin loops that read a sequence folder, run the segmenter and feed
frames to a :class:`~.mapper.Mapper` whose deltas live in the output folder.

Output folder (format details in docs/mapping.md; file formats in :mod:`panovocc_cli.io.mapstore`)::

    OUT/config.json        resolved MapConfig (SEQ, poses file, every parameter)
    OUT/memory.npz         the memory: non-zero voxels in key order, integer channels, frames_done, poses
    OUT/deltas/NNNNNN.npz  each frame's sparse delta (keys, channels, the pose it was computed under)
    OUT/poses.txt          the poses the retained deltas were computed under (NICE-SLAM form)
    OUT/prediction.npz     CONVENTIONS.md grid: occupied voxels carry a vocabulary class (1..C) or 254,
                           0 free, 255 unobserved; class_names = ["empty"] + vocabulary
    OUT/map.ply            occupied voxel centres, coloured by class (or mean RGB / height)

The run's configuration (:class:`MapConfig`: sequence, output, pose file, checkpointing, segmenter) holds
the mapper's (:meth:`MapConfig.mapper_config`: geometry, occupancy, vocabulary, GSC, evidence weights).
Per frame the loop reads the images (:meth:`io.sequence.Sequence.frame`), runs the segmenter unless it
is ``none`` (its logits go into the Frame) and calls ``Mapper.integrate``. ``revise`` hands the changed
poses to ``Mapper.revise``, which recomputes those frames from the folder through the same reader.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from ..config import validate_config
from ..errors import PanovoccError
from ..frame import Frame
from ..io import mapstore
from ..io.atomic import check_outputs, clean_temporaries, write_text
from ..io.grid import read_grid, write_grid
from ..io.ply import write_ply_points
from ..io.poses import frame_poses, read_first_pose, write_poses
from ..io.sequence import Sequence, read_meta
from .ablation import CorrectionSchedule, check_resumable
from .config import (FIRST_POSE_REFERENCE, PLY_COLORS, POSES_SLAM, RIGID, SEGMENTER_AUTO, SEGMENTER_NONE, MapConfig,
                     MapperConfig, ReviseConfig, SemanticParams, check_key_reach, frame_ids,
                     several_sequences)
from .export import point_chunks
from .mapper import Mapper
from .rpu import FROZEN, has_store

CONFIG_NAME = mapstore.CONFIG_NAME
MEMORY_NAME = mapstore.MEMORY_NAME


def resolve_semantic(p: SemanticParams, seq: Sequence) -> SemanticParams:
    """Resolve the segmenter spec, the vocabulary and a precomputed folder against the sequence to be
    mapped; validate everything before any file is written.

    ``auto`` is the simulated segmenter when the sequence has ``semantic/`` labels, else ``none``
    (geometry only): the Python API's leniency; the ``map`` command refuses an unlabelled sequence
    without an explicit ``--segmenter`` instead (cli/map_cmds.py).

    Raises
    ------
    PanovoccError
        Empty/invalid vocabulary, unknown segmenter, negative noise, ``simulated`` on a sequence without
        labels, a precomputed folder that fails validation, bad ply_color.
    """
    from ..classes import parse_vocab
    from ..semantics.registry import SIMULATED, build_segmenter, is_simulated

    if p.ply_color not in PLY_COLORS:
        raise PanovoccError(f"--ply-color must be one of {', '.join(PLY_COLORS)}, got {p.ply_color!r}")
    # an empty vocabulary is an error even for --segmenter none; 'all' = the sequence's classes
    vocab = parse_vocab(p.vocab, seq.meta.class_names if seq.has_labels else None, what="vocabulary (--vocab)")
    spec = p.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        spec = SIMULATED if seq.has_labels else SEGMENTER_NONE
    if spec == SEGMENTER_NONE:
        if p.features:
            raise PanovoccError("--features needs a segmenter that gives embeddings (--segmenter simulated or clip), "
                                "not none")
        return dataclasses.replace(p, segmenter=SEGMENTER_NONE, vocab=[])
    if is_simulated(spec) and not seq.has_labels:
        raise PanovoccError("the simulated segmenter needs ground-truth labels (semantic/), which this sequence "
                            "lacks: pass --segmenter precomputed:DIR or --segmenter none", seq.root)
    if spec.startswith("precomputed:"):
        folder = spec[len("precomputed:"):]
        spec = "precomputed:" + (str(Path(folder).resolve()) if folder else "")
    seg = build_segmenter(spec, seed=int(p.seed), noise=float(p.noise))  # validates spec, noise, folder
    if p.features:
        from ..semantics.segmenter import Segmenter

        if type(seg).features is Segmenter.features:
            seg.features(None)  # its one-line refusal, naming the segmenters that give embeddings
    return dataclasses.replace(p, segmenter=seg.spec or spec, vocab=list(vocab))


def auto_stride(width: int) -> int:
    """Default kernel stride for an ERP ``width``: 256 samples around the panorama (4 at 1024)."""
    return max(1, width // 256)


def auto_semantic_stride(width: int) -> int:
    """Default semantic stride for an ERP ``width``: 512 measurements around the panorama (2 at 1024;
    docs/semantics.md, "Semantic stride", has the measurement behind it)."""
    return max(1, width // 512)


# ---------------------------------------------------------------------------------------------
# frames: the sequence reader and the segmenter


class SequenceFrames:
    """The map commands' frame source: frame ``i`` of a sequence folder, with the segmenter's logits.

    Callable as ``frames(i) -> Frame`` (the run loop's frames, segmented); :meth:`read` gives the frame
    without segmenting it (what ``Mapper(frame_source=...)`` asks for on ``revise``: the semantics of a
    revised frame come from the observation kept with its delta). The segmenter runs here, in the run loop,
    never inside the mapper.

    Parameters
    ----------
    seq : Sequence
    segmenter : semantics.segmenter.Segmenter or None (geometry only)
    vocab : list of str, the run's vocabulary (the logits' C classes)
    stride : int, the semantic stride s: the segmenter sees the image at pixels (s i, s j) and its logits
        are those pixels' (the mapper measures only there)
    features : also ask the segmenter for its per-pixel embeddings (a map made with ``--features``)
    """

    def __init__(self, seq: Sequence, segmenter=None, vocab=(), stride: int = 1, features: bool = False):
        self.seq = seq
        self.features = bool(features) and segmenter is not None
        self.stride = int(stride)
        self.segmenter = segmenter
        self.vocab = list(vocab)
        self.segmenter_seconds = 0.0  # time spent in the segmenter (run summaries)

    def read(self, i: int) -> Frame:
        """Frame ``i`` without segmenting it: what a revision needs (``Mapper(frame_source=frames.read)``;
        its semantics come from the observation kept with the frame's delta)."""
        return self.seq.frame(i)

    def __call__(self, i: int) -> Frame:
        frame = self.seq.frame(i)
        if self.segmenter is not None:  # no ground truth in the call: frame_id = the frame's index
            t0 = time.perf_counter()
            s = self.stride
            rgb = frame.rgb[::s, ::s] if s > 1 else frame.rgb
            frame.logits = self.segmenter.logits(rgb, self.vocab, frame_id=i)
            if self.features:
                frame.features = self.segmenter.features(rgb, frame_id=i)
            self.segmenter_seconds += time.perf_counter() - t0
        return frame


def sequence_frames(cfg: MapConfig, seq: Sequence) -> SequenceFrames:
    """The frame source of a resolved config (the segmenter is built once, here)."""
    if not cfg.semantic.enabled:
        return SequenceFrames(seq)
    from ..semantics.registry import build_segmenter
    from ..semantics.simulated import sequence_label_source

    s = cfg.semantic
    labels = sequence_label_source(seq) if seq.has_labels else None  # the simulator's ground truth
    seg = build_segmenter(s.segmenter, seed=int(s.seed), noise=float(s.noise), label_source=labels)
    return SequenceFrames(seq, seg, s.vocab, stride=int(s.weights.stride), features=s.features)


def concurrent_kernels_safe() -> bool:
    """Whether numba's parallel kernels may be launched from two threads at once: true for the OpenMP and
    TBB threading layers, false for workqueue (which aborts the process on concurrent launches) or before
    any parallel kernel has run (no layer chosen yet)."""
    import numba

    try:
        return numba.threading_layer() in ("omp", "tbb")
    except ValueError:  # no parallel kernel has run yet
        return False


def prefetched(frames, indices):
    """``(i, frames(i))`` for ``i`` in ``indices``, reading and segmenting frame ``i + 1`` on a second
    thread while the caller integrates frame ``i`` (PNG decoding and zlib release the GIL, the kernels
    run in parallel). The frames are the same objects, in the same order, as a plain loop would give:
    the segmenters are seeded per frame. The first frame is read on the calling thread; the prefetching
    starts only once :func:`concurrent_kernels_safe` says so, else the loop stays sequential."""
    from concurrent.futures import ThreadPoolExecutor

    indices = list(indices)
    if not indices:
        return
    pool = None
    pending = None
    try:
        for k, i in enumerate(indices):
            frame = pending.result() if pending is not None else frames(i)
            pending = None
            if k + 1 < len(indices) and (pool is not None or (k > 0 and concurrent_kernels_safe())):
                if pool is None:
                    pool = ThreadPoolExecutor(max_workers=1)
                pending = pool.submit(frames, indices[k + 1])
            yield i, frame
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def observed(frames, mapper: Mapper):
    """``frames`` (``i -> Frame``) as ``i -> (frame, observation)``: the frame's semantic observation made where
    it is read (:meth:`.Mapper.observe`), the frame without its logits and features (C floats a pixel; the
    observation is 4 bytes a pixel), so a prefetched frame and the one being integrated hold no logits. The
    same delta as :meth:`.Mapper.integrate` of the frame as read (docs/mapping.md, "Memory layout")."""
    def read(i: int):
        frame = frames(i)
        observation = mapper.observe(frame)
        if observation is not None:
            frame = dataclasses.replace(frame, logits=None, features=None)
        return frame, observation

    return read


def resident_mb() -> float:
    """This process's resident memory now, MB (Linux ``/proc/self/statm``; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError):
        return float("nan")


def write_exports(out: Path, mapper: Mapper, ply_color: str, ex=None) -> dict:
    """Write ``prediction.npz`` and ``map.ply`` of the mapper's current memory (``ex``: its export when the
    caller already made it); return the counts (occupied, free and, with semantics, classed voxels)."""
    if ex is None:
        ex = mapper.export()
    write_grid(out / "prediction.npz", ex.grid)
    chunks = point_chunks(ex, mapper.config.geometry.voxel_size, ply_color, mapper.config.vocab)
    write_ply_points(out / "map.ply", chunks, count=len(ex.occupied_keys))  # a slice of the points at a time
    return ex.summary()


# ---------------------------------------------------------------------------------------------
# map


def run_poses(cfg: MapConfig) -> np.ndarray | None:
    """The run's poses (n, 4, 4) float64, or None when the sequence's own ``poses.txt`` is read as it is.

    ``--poses FILE``: one pose per frame (io/poses.py ``frame_poses``: NICE-SLAM line i = frame i, TUM
    timestamps matched to frame indices), aligned to ``poses_reference`` (default SEQ/poses.txt) by
    ``poses_align`` (Umeyama se3/sim3, or se3-pose: the whole poses). ``--poses slam``: placeholders,
    :func:`slam_first_poses` (the front end places the frames; SEQ/poses.txt is never read unless ``--first-pose
    reference`` names it).
    """
    meta = Path(cfg.seq) / "meta.json"
    if not meta.is_file():
        return None  # Sequence says what is wrong
    n = read_meta(cfg.seq).frames
    if cfg.poses == POSES_SLAM:
        return slam_first_poses(cfg, n)
    if cfg.poses is None and cfg.poses_align == "none":
        return None
    poses = frame_poses(cfg.poses if cfg.poses is not None else Path(cfg.seq) / "poses.txt", n)
    if cfg.poses_align != "none":
        from ..evaluation.trajectory import align_trajectory

        poses = align_trajectory(poses, frame_poses(cfg.reference_path(), n), cfg.poses_align)[0]
    return poses


def _move_unplaced(mapper: Mapper, frames, unplaced: list, A: np.ndarray) -> None:
    """``--poses slam --poses-align se3``: the frames the tracker could not place (empty observations at the last
    placed frame's pose) follow the rigid motion ``A`` the placed ones were moved by, still empty (a frame without
    depth), so that ``poses.txt`` is in one world. Nothing to do while ``A`` is the identity."""
    if np.array_equal(A, np.eye(4)):
        return
    for fid in unplaced:
        frame = frames.read(fid)
        mapper.revise(fid, A @ mapper.pose(fid), dataclasses.replace(frame, depth=np.zeros_like(frame.depth)))


def slam_first_poses(cfg: MapConfig, n: int) -> np.ndarray:
    """The world of a ``--poses slam`` run: (n, 4, 4) float64, the pose each frame gets should it be the first
    the front end places (the tracker's ``T_world_first``; also the run's placeholder poses, from which the
    map's origin is chosen). ``--first-pose FILE``: that file's one pose (:func:`~..io.poses.read_first_pose`)
    for every frame; ``--first-pose reference`` and ``--poses-align se3``: the reference trajectory's poses
    (``--poses-reference``, default SEQ/poses.txt, read as ``--poses-align`` reads it: the run starts in the
    reference's world, which the final fit then corrects by millimetres, so a reference far from the world
    origin keeps the map's keys in range); none: identity (the tracker then levels the first frame at the
    origin, :data:`~..slam.tracker.LEVEL_FIRST`)."""
    if cfg.first_pose == FIRST_POSE_REFERENCE or (cfg.first_pose is None and cfg.poses_align in RIGID):
        return frame_poses(cfg.reference_path(), n)
    if cfg.first_pose is None:
        return np.tile(np.eye(4), (n, 1, 1))
    return np.tile(read_first_pose(cfg.first_pose), (n, 1, 1))


def _open_sequence(cfg: MapConfig, poses: np.ndarray | None = None) -> Sequence:
    if poses is None:
        poses = run_poses(cfg)
    seq = Sequence(cfg.seq, None if cfg.poses == POSES_SLAM else cfg.poses, poses)
    if seq.meta.camera != "erp":
        raise PanovoccError(f"camera {seq.meta.camera!r}: the mapper supports ERP sequences only",
                            Path(cfg.seq) / "meta.json")
    if len(seq) == 0:
        raise PanovoccError("sequence has no frames", Path(cfg.seq) / "meta.json")
    return seq


def resolve(cfg: MapConfig, width: int) -> MapConfig:
    """Fill the automatic stride and check parameter ranges."""
    cfg = validate_config(cfg)  # the ranges declared on the fields (config.py option)
    g = cfg.geometry
    stride = cfg.stride if cfg.stride > 0 else auto_stride(width)
    sem_stride = cfg.semantic_stride if cfg.semantic_stride > 0 else auto_semantic_stride(width)
    if not (np.isfinite(g.max_range) and g.max_range > g.min_range):  # across two fields: not a declared range
        raise PanovoccError(f"--max-range must be a distance in metres above min_range {g.min_range}, got {g.max_range}")
    weights = dataclasses.replace(cfg.semantic.weights, stride=sem_stride)
    # the face resolution reads channel P: a run with --resolve records it
    cfg = dataclasses.replace(cfg, geometry=dataclasses.replace(g, stride=stride,
                                                                offsets=g.offsets or cfg.occupancy.resolve),
                              semantic=dataclasses.replace(cfg.semantic, weights=weights),
                              seq=str(Path(cfg.seq).resolve()), out=str(Path(cfg.out).resolve()),
                              poses=cfg.poses if cfg.poses in (None, POSES_SLAM) else str(Path(cfg.poses).resolve()),
                              poses_reference=None if cfg.poses_reference is None
                              else str(Path(cfg.poses_reference).resolve()),
                              first_pose=cfg.first_pose if cfg.first_pose in (None, FIRST_POSE_REFERENCE)
                              else str(Path(cfg.first_pose).resolve()))
    MapperConfig(geometry=cfg.geometry, occupancy=cfg.occupancy, origin=cfg.origin).check()
    return cfg


def resolve_origin(cfg: MapConfig, poses: np.ndarray) -> MapConfig:
    """The run's local origin (``--origin``, or the first frame's voxel), snapped to the lattice, and
    every frame checked against the reach of the keys before any work: one line naming the first frame
    outside it (``poses`` (n, 4, 4) float64, world)."""
    from ..geometry.lattice import key_reach, local_origin

    check_key_reach(cfg.geometry)
    h = cfg.geometry.voxel_size
    if cfg.origin is not None:  # the lattice point nearest the given origin
        o = local_origin(np.asarray(cfg.origin, np.float64) + 0.5 * h, h)
    else:  # the voxel of the first frame's camera
        o = local_origin(poses[0, :3, 3] if len(poses) else np.zeros(3), h)
    reach = key_reach(h) - cfg.geometry.max_range
    far = np.abs(poses[:, :3, 3] - o * h).max(axis=1) if len(poses) else np.zeros(0)
    bad = np.flatnonzero(~(far < reach))
    if len(bad):
        i = int(bad[0])
        raise PanovoccError(f"frame {i}: camera at {np.round(poses[i, :3, 3], 3).tolist()} m is {far[i]:.0f} m from "
                            f"the map's origin {(o * h).tolist()} m; voxel keys reach {reach:.0f} m at {h} m voxels "
                            "less --max-range (give --origin nearer the capture, or a larger --voxel-size)")
    return dataclasses.replace(cfg, origin=[float(x) for x in o * h])


REVISIONS_PER_CHECKPOINT = 1000
"""A pose source's revisions after one frame (``--poses slam``: a loop closure's, or the final refinement's of
every frame) are committed this many at a time, so a checkpoint can compact the delta log during a long pass
(docs/mapping.md, "Compaction of the delta log"); ``--checkpoint-every 0`` commits only at the end."""

_OUTPUTS = (CONFIG_NAME, MEMORY_NAME, "poses.txt", "prediction.npz", "map.ply", "trajectory.tum", "slam.json")


def _check_inputs(cfg: MapConfig, seq: Sequence) -> None:
    """What can be checked cheaply before the first write: every frame's files present, their PNG headers
    (size, bit depth, channels, a whole file), and a precomputed segmentation's file for every frame."""
    from ..io.sequence import frame_stem

    spec = cfg.semantic.segmenter if cfg.semantic.enabled else ""
    labels = ("semantic",) if spec == "simulated" or (seq.root / "semantic").is_dir() else ()
    rgb = ("rgb",) if spec or (seq.root / "rgb").is_dir() else ()  # colours are read even without a segmenter
    seq.check_files(("depth",) + rgb + labels)
    if spec.startswith("precomputed:"):
        from ..classes import canonical_name
        from ..io.precomputed import read_vocab_json

        folder = Path(spec[len("precomputed:"):])
        known = set(read_vocab_json(folder))
        if not any(canonical_name(v) in known for v in cfg.semantic.vocab):
            raise PanovoccError(f"none of the vocabulary words {list(cfg.semantic.vocab)} appear in vocab.json "
                                f"{sorted(known)}", folder / "vocab.json")
        for i in range(len(seq)):
            stem = frame_stem(i)
            if not ((folder / f"{stem}.npz").is_file() or (folder / f"{stem}.png").is_file()):
                raise PanovoccError(f"frame {stem} not found (expected {stem}.npz or {stem}.png)", folder)


@contextlib.contextmanager
def _writer_lock(out: Path):
    """Hold OUT/.lock (one writer per map folder, io/lock.py), then clear the temporaries a killed run left."""
    from ..io.lock import FolderLock

    if not out.is_dir():
        raise PanovoccError("map output folder not found", out)
    with FolderLock(out):
        clean_temporaries(out, _OUTPUTS)
        if (out / mapstore.DELTAS_DIR).is_dir():
            for pattern in (".*.npz", ".*.pvj"):  # snapshot and journal temporaries (legacy: delta files)
                for tmp in (out / mapstore.DELTAS_DIR).glob(pattern):
                    tmp.unlink(missing_ok=True)
        yield


EXPORT_RECORD = "export.json"
"""In ``deltas/``: the SHA-256 of the memory snapshot that ``prediction.npz`` was exported from, of
``prediction.npz`` and of the mapper's settings (``MapperConfig.to_json``: not the run's own fields, so two runs
of the same map write the same record); written after the commit that saved the snapshot (``map``, ``revise``). While it
still describes the folder, ``revise`` labels again only the GSC cubes near the voxels it changes and takes
the other labels from ``prediction.npz`` (the same labels as a whole export, bit for bit: docs/mapping.md
"Incremental revise export"); a folder it does not describe (a run killed after its commit, a file
changed by hand, a map made before it) gets the whole export."""


def _settings_sha256(mapper: Mapper) -> str:
    """SHA-256 of the settings an export depends on (the mapper's ``config.json`` sections, canonical JSON)."""
    import hashlib

    return hashlib.sha256(json.dumps(mapper.config.to_json(), sort_keys=True).encode()).hexdigest()


def record_export(out: Path, mapper: Mapper) -> None:
    """Write :data:`EXPORT_RECORD` for the exports and the memory snapshot now in ``out`` (call after the
    commit of the save that wrote the snapshot, once ``prediction.npz`` is written)."""
    from .rpu import SNAPSHOT_NAME, sha256_file

    with np.load(out / mapstore.DELTAS_DIR / SNAPSHOT_NAME, allow_pickle=False) as z:
        memory = str(z["memory_sha256"])
    rec = {"memory_sha256": memory, "prediction_sha256": sha256_file(out / "prediction.npz"),
           "settings_sha256": _settings_sha256(mapper)}
    write_text(out / mapstore.DELTAS_DIR / EXPORT_RECORD, json.dumps(rec, indent=1) + "\n")


def export_is_current(out: Path, mapper: Mapper) -> bool:
    """Whether ``out/prediction.npz`` is the export of ``mapper``'s memory as :meth:`Mapper.load` read it
    from ``out`` (its memory.npz with no record after it, and :data:`EXPORT_RECORD` naming that file,
    prediction.npz as it is and the mapper's settings)."""
    from .rpu import sha256_file

    loaded, path = mapper._rpu.loaded_snapshot, out / mapstore.DELTAS_DIR / EXPORT_RECORD
    if loaded is None or not path.is_file() or not (out / "prediction.npz").is_file():
        return False
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (isinstance(rec, dict) and rec.get("memory_sha256") == loaded
            and rec.get("settings_sha256") == _settings_sha256(mapper)
            and rec.get("prediction_sha256") == sha256_file(out / "prediction.npz"))


def _require_deltas(out: Path) -> None:
    """revise and ``map --resume`` re-read the frames' deltas: a map folder without ``deltas/`` (a benchmark
    cache's map keeps only its outputs) is refused before anything is written."""
    if not (out / mapstore.DELTAS_DIR).is_dir():
        raise PanovoccError(f"{mapstore.DELTAS_DIR}/ not found: this map's delta store was removed (only its outputs "
                            "are left), so it cannot be revised or resumed; map the sequence again", out)


def load_config(out: str | Path) -> MapConfig:
    """The resolved :class:`MapConfig` of a map run's output folder (refused for a merge of several
    sequences' maps, which revise and resume cannot read frames for)."""
    raw = mapstore.read_map_config(out)
    if several_sequences(raw):
        raise PanovoccError("a merge of maps of several sequences cannot be revised or resumed (its frame ids name "
                            "no one sequence's frames): revise or resume the input maps and merge them again", out)
    return MapConfig.from_json(raw, Path(out) / CONFIG_NAME)


def _remove_unless_started(out: Path) -> None:
    """Remove the output folder this run created when it holds no ``config.json`` (the run failed before
    its first output); a folder that holds one is a resumable run and stays."""
    if out.is_dir() and not (out / CONFIG_NAME).exists():
        shutil.rmtree(out, ignore_errors=True)


def map_inputs(cfg: MapConfig) -> tuple:
    """The paths a map run reads (no output may be one or lie inside one): the sequence, the pose file and the
    reference of --poses-align, a precomputed:DIR segmenter's folder, a --first-pose FILE (None entries where
    not used)."""
    from ..semantics.registry import PRECOMPUTED

    seg = cfg.semantic.segmenter
    return (cfg.seq, None if cfg.poses == POSES_SLAM else cfg.poses, cfg.poses_reference,
            seg[len(PRECOMPUTED):] if seg.startswith(PRECOMPUTED) else None,
            None if cfg.first_pose == FIRST_POSE_REFERENCE else cfg.first_pose)


def open_frames(cfg: MapConfig) -> SequenceFrames:
    """The frame source of a resolved run config (its sequence, poses and segmenter): what a shard worker
    reads its frames through (benchmark/sharded.py)."""
    return sequence_frames(cfg, _open_sequence(cfg))


def run_map(cfg: MapConfig | None = None, resume_out: str | Path | None = None, overwrite: bool = False,
            progress: bool = True, stop_after: int | None = None, pose_source=None, observer=None,
            shards=None) -> dict:
    """Map a sequence (or resume an interrupted run in ``resume_out``).

    Parameters
    ----------
    cfg : MapConfig for a new run (ignored when resuming)
    resume_out : output folder of an interrupted run; its config.json supplies everything else
    overwrite : replace an existing map output in ``cfg.out``
    stop_after : stop after this many frames as if killed there (no final save; tests of ``--resume``)
    pose_source : for ``cfg.poses == "slam"``: a callable ``(Sequence) -> source`` whose ``source(i, frame)``
        returns ``(T_world_cam (4, 4) or None, revisions [(frame id, T_world_cam)])`` for each frame in order
        (slam/run.py). A frame it cannot place (None) is integrated as an empty observation at the last
        placed pose (so every frame has an id and a line in OUT/poses.txt) and listed in ``unplaced_frames``;
        each revision is applied at once with ``Mapper.revise``.
    observer : optional; ``observer.frame(i, frame, mapper, revisions)`` is called after each frame is
        integrated (and its revisions applied), ``observer.finish(mapper, summary)`` once the exports are
        written (viz/live.py: the Rerun live log). It only reads; the map is the same with or without it.
    shards : optional; the frames are integrated elsewhere: ``shards(mapper, cfg, ids)`` keeps each frame's
        record in ``mapper`` in frame order (``Mapper.keep_encoded``), yielding its id after each, and adds
        the exact sum of their deltas (``Mapper.add_sum``) before it ends (benchmark/sharded.py: Dask
        workers). The folder's bytes are those of the run in this process. A driver with a ``progress``
        attribute is handed the progress bar and moves it itself (frames as the workers integrate them).

    Returns
    -------
    summary : dict (frames, integrated, occupied, free, [classed], ms_per_frame, update_ms_per_frame,
        [segmenter_ms_per_frame], empty_frames: ids of frames with no valid depth, mapped as empty
        observations)
    """
    with contextlib.ExitStack() as held:  # the folder lock (io/lock.py), taken once the folder is known
        return _run_map(cfg, resume_out, overwrite, progress, stop_after, held, pose_source, observer, shards)


def _check_shardable(cfg: MapConfig, observer) -> None:
    """A sharded run integrates frames apart, on other processes: refuse what needs them in order, here."""
    if cfg.poses == POSES_SLAM or cfg.ablation.perturbs or observer is not None or cfg.frame_times:
        raise PanovoccError("a sharded run (--workers/--scheduler) maps frames independently: it cannot be combined "
                            "with --poses slam, the drift ablation, a live log or --frame-times")


def _run_map(cfg, resume_out, overwrite, progress, stop_after, held: contextlib.ExitStack, pose_source=None,
             observer=None, shards=None) -> dict:
    if resume_out is not None:
        out = Path(resume_out)
        held.enter_context(_writer_lock(out))
        cfg = load_config(out)
        if shards is not None:
            _check_shardable(cfg, observer)
        check_resumable(cfg.ablation, out / CONFIG_NAME)
        if cfg.poses == POSES_SLAM:
            raise PanovoccError("a --poses slam run cannot be resumed (the tracker's state is not saved); start over "
                                "with --overwrite", out)
        seq = _open_sequence(cfg)
        frames = sequence_frames(cfg, seq)
        todo = frame_ids(cfg.frames, len(seq))  # the run's frames (--frames: a part of the sequence)
        if has_store(out):
            _require_deltas(out)
            mapper = Mapper.load(out, frame_source=frames.read, roll_back=True)  # a truncated log: as if killed
            start = len(mapper)
            ids = np.asarray(mapper.frame_ids)
            saved = np.stack([mapper.pose(i) for i in ids]) if start else np.zeros((0, 4, 4))
            if start > len(todo) or not np.array_equal(ids, todo[:start]) or not np.array_equal(
                    saved, seq.poses[todo[:start]]):
                mapper.close()
                raise PanovoccError("the sequence's poses changed since the run started (use revise)", out)
        else:
            mapper, start = Mapper(cfg.mapper_config(), folder=out, frame_source=frames.read), 0
    else:
        if cfg is None:
            raise ValueError("run_map needs a config or resume_out")
        cfg = validate_config(cfg)
        if shards is not None:
            _check_shardable(cfg, observer)
        if (cfg.poses == POSES_SLAM) != (pose_source is not None):
            raise PanovoccError("--poses slam needs a pose source (panovocc map, or slam.run.run_map_slam)"
                                if pose_source is None else "a pose source is only used with --poses slam")
        if cfg.revise_per_frame and cfg.poses != POSES_SLAM:
            raise PanovoccError("--revise-per-frame spreads the revisions of --poses slam's optimisations; a pose "
                                "file is not revised while mapping")
        if cfg.heading_prior and cfg.poses != POSES_SLAM:
            raise PanovoccError("--heading-prior holds the headings of --poses slam's keyframes; a pose file is not "
                                "refined")
        if cfg.slam_preset != "default" and cfg.poses != POSES_SLAM:
            raise PanovoccError("--slam-preset sets the parameters of --poses slam's front end; a pose file has none")
        if cfg.slam_params is not None and cfg.poses != POSES_SLAM:
            raise PanovoccError("--slam-params sets the parameters of --poses slam's front end; a pose file has none")
        if cfg.first_pose is not None and cfg.poses != POSES_SLAM:
            raise PanovoccError("--first-pose sets the world of --poses slam; a pose file's world is its own (move it "
                                "into a reference's with --poses-align se3)")
        if cfg.poses == POSES_SLAM and cfg.poses_align == "sim3":
            raise PanovoccError("--poses slam --poses-align sim3: the front end's poses are metric (they come from the "
                                "depth), and a scale fitted to the reference would move the frames but not scale "
                                "their depth; use --poses-align se3 or se3-pose")
        if cfg.poses == POSES_SLAM and cfg.poses_align != "none" and cfg.first_pose is not None:
            raise PanovoccError("--first-pose and --poses-align both set the world of --poses slam: give one")
        if cfg.poses == POSES_SLAM and cfg.poses_align == "none" and (
                cfg.poses_reference is not None and cfg.first_pose != FIRST_POSE_REFERENCE):
            raise PanovoccError("--poses-reference with --poses slam is the reference of --poses-align se3 (the "
                                "final poses fitted to it) or of --first-pose reference: give one of them")
        if cfg.poses == POSES_SLAM and cfg.frames is not None:
            raise PanovoccError("--frames maps a part of a sequence with known poses; --poses slam tracks the whole "
                                "sequence from its first frame")
        if cfg.poses == POSES_SLAM and cfg.ablation.perturbs:
            raise PanovoccError("the drift-and-correction ablation perturbs given poses; it cannot be combined with "
                                "--poses slam")
        seq = _open_sequence(cfg)
        todo = frame_ids(cfg.frames, len(seq))  # a bad --frames range: one line, before any write
        cfg = resolve_origin(resolve(cfg, seq.meta.width), seq.poses)
        cfg = dataclasses.replace(cfg, semantic=resolve_semantic(cfg.semantic, seq))
        frames = sequence_frames(cfg, seq)  # builds the segmenter: fails before any file is written
        out = Path(cfg.out)
        check_outputs([(out, "map", True), (cfg.frame_times, "frame times", False)], overwrite, inputs=map_inputs(cfg))
        _check_inputs(cfg, seq)  # every frame present with the right size and type, before the first write
        if frames.segmenter is not None:
            frames.segmenter.prepare()  # a network's weights and device: a failure here leaves nothing
        if not (out.exists() or out.is_symlink()):  # a run that fails before config.json leaves nothing behind
            held.callback(_remove_unless_started, out)
        out.mkdir(parents=True, exist_ok=True)
        held.enter_context(_writer_lock(out))
        if (out / CONFIG_NAME).exists():
            if not overwrite:
                raise PanovoccError("already holds a map (use --resume to continue it, --overwrite to start over)",
                                    out)
            for name in _OUTPUTS:
                (out / name).unlink(missing_ok=True)
            shutil.rmtree(out / mapstore.DELTAS_DIR, ignore_errors=True)
        out.mkdir(parents=True, exist_ok=True)
        mapstore.write_map_config(out, cfg.to_json())
        if pose_source is None:
            write_poses(out / "poses.txt", seq.poses)
        mapper, start = Mapper(cfg.mapper_config(), folder=out, frame_source=frames.read), 0
    n = len(todo)  # the frames this run maps (--frames: a part of the sequence; ids are the sequence's indices)
    end = n if stop_after is None else min(n, stop_after)
    from tqdm import tqdm

    t0 = time.perf_counter()
    t_compute = t_track = 0.0
    schedule = CorrectionSchedule(seq.poses, cfg.ablation) if cfg.ablation.perturbs else None
    corrected = 0
    online = pose_source(seq) if pose_source is not None else None
    unplaced: list[int] = []
    last_T = seq.poses[0].copy() if online is not None else np.eye(4)  # SLAM: the world's first pose (placeholder)
    bar = tqdm(desc="map", unit="frame", file=sys.stderr, disable=not progress, initial=start, total=n)
    times = [] if cfg.frame_times else None
    c0 = time.process_time()
    # the ablation schedule and the SLAM revisions read frames again: no prefetching thread beside them
    run_ids = [int(i) for i in todo[start:end]]
    todo_pos = {fid: start + k for k, fid in enumerate(run_ids)}  # frame id -> frames of the run before it
    stream = (() if shards is not None else prefetched(observed(frames, mapper), run_ids)
              if schedule is None and online is None else ((i, (frames(i), None)) for i in run_ids))
    try:
        for i, (frame, observation) in stream:
            revisions = []
            if schedule is not None:  # the ablation schedule: drifted pose now, the true one later
                frame.T_world_cam = schedule.integration_pose(i)
            if online is not None:
                tc = time.perf_counter()
                T, revisions = online(i, frame)
                revisions = list(revisions)
                t_track += time.perf_counter() - tc
                if T is None:  # not placed: an empty observation where the last placed frame was
                    unplaced.append(i)
                    frame = dataclasses.replace(frame, depth=np.zeros_like(frame.depth), T_world_cam=last_T)
                else:
                    frame.T_world_cam = last_T = np.asarray(T, np.float64)
            tc = time.perf_counter()
            mapper.integrate(frame, observation)
            if schedule is not None:
                corrected += schedule.apply(mapper, frames, i)
            for k in range(0, len(revisions), REVISIONS_PER_CHECKPOINT):  # a loop closure's frames, pipelined
                if k and cfg.checkpoint_every:  # a long pass (the final refinement, every frame): its log compacts
                    mapper.checkpoint(background=True)
                mapper.revise_many((fid, T, None) for fid, T in revisions[k:k + REVISIONS_PER_CHECKPOINT])
            t_frame = time.perf_counter() - tc
            t_compute += t_frame
            if observer is not None:
                observer.frame(i, frame, mapper, revisions)
            bar.update(1)
            done = todo_pos[i] + 1
            ck = bool(cfg.checkpoint_every and done % cfg.checkpoint_every == 0 and done < n)
            if ck:
                mapper.checkpoint(background=True)  # a COMMIT record after the pending delta writes
            if times is not None:
                times.append((i, time.perf_counter() - t0, time.process_time() - c0, 1e3 * t_frame, int(ck),
                              resident_mb()))
        if unplaced and getattr(online, "alignment", None) is not None:
            _move_unplaced(mapper, frames, unplaced, online.alignment)
        counted = shards is not None and hasattr(shards, "progress")  # the driver moves the bar as frames are done
        if counted:
            shards.progress = bar
        for i in (shards(mapper, cfg, run_ids) if shards is not None else ()):  # records kept in frame order
            if not counted:
                bar.update(1)
            done = todo_pos[i] + 1
            if cfg.checkpoint_every and done % cfg.checkpoint_every == 0 and done < n:
                mapper.checkpoint(background=True)
    except (PanovoccError, OSError) as e:  # found mid-run: say what is on disk and what can be done with it
        what = str(e) if isinstance(e, PanovoccError) else f"{e.filename}: {e.strerror or e}"
        if cfg.poses == POSES_SLAM:  # --resume refuses these (the tracker's state is not saved)
            raise PanovoccError(f"{what} -- the --poses slam run in {out} stopped and cannot be resumed: fix the "
                                f"input and start over with --overwrite") from None
        raise PanovoccError(f"{what} -- the map in {out} is resumable: fix the input and run "
                            f"panovocc map --resume {out} (or start over with --overwrite)") from None
    finally:
        mapper.close()
        bar.close()
        if times is not None:
            write_text(cfg.frame_times, "frame,t_s,cpu_s,update_ms,checkpoint,rss_mb\n" + "".join(
                f"{i},{t:.4f},{cpu:.4f},{u:.3f},{c},{r:.1f}\n" for i, t, cpu, u, c, r in times))
    wall = time.perf_counter() - t0
    steps = max(end - start, 1)
    summary = {"frames": n, "integrated": end - start, "ms_per_frame": 1e3 * wall / steps,
               "update_ms_per_frame": 1e3 * t_compute / steps, "out": str(out),
               "empty_frames": [f for f in mapper.empty_frames if f not in set(unplaced)]}
    if online is not None:
        summary.update(unplaced_frames=unplaced, track_ms_per_frame=1e3 * t_track / steps)
    if frames.segmenter is not None:
        summary["segmenter_ms_per_frame"] = 1e3 * frames.segmenter_seconds / steps
    if schedule is not None:
        summary["corrected"] = corrected
    if end < n:
        summary.update(stopped_at=end)
        return summary
    from ..runtime import release_freed_heap

    release_freed_heap()  # the frames' freed temporaries, before the export's and the save's
    # the export (GSC labels, grid, PLY), then memory.npz once the export is gone: the two largest sets of
    # temporaries never stack (peak RSS, docs/mapping.md "Memory layout"; on the building, 290 MB less
    # than memory.npz compressing beside the grid and PLY writes, for the same time)
    try:
        ex = mapper.export()
        summary.update(write_exports(out, mapper, cfg.semantic.ply_color, ex))
        del ex
        release_freed_heap()
        mapper.save(out)
    finally:
        mapper.close()  # re-raises a failed delta write
    record_export(out, mapper)  # prediction.npz is this commit's memory's export: a later revise can relabel a part
    done = mapper._rpu.store.compactions  # a run that revises (--poses slam) compacts its log as it goes
    if done:
        summary["compactions"] = {"count": len(done), "shards": sum(c[0] for c in done),
                                  "freed_bytes": sum(c[1] for c in done), "copied_bytes": sum(c[2] for c in done),
                                  "log_bytes": mapper._rpu.store.log_bytes()}
    if observer is not None:
        observer.finish(mapper, summary)
    return summary


# ---------------------------------------------------------------------------------------------
# revise


def run_revise(cfg: ReviseConfig | str | Path, poses_path: str | Path | None = None, progress: bool = True) -> dict:
    """Re-integrate exactly the frames whose pose differs in ``cfg.poses``; rewrite memory and exports.

    Called as ``run_revise(ReviseConfig(out, poses))`` or, as before, ``run_revise(out, poses_path,
    progress)``.

    ``poses_path`` is a full pose file (one pose per frame), read as ``map --poses`` reads it
    (:func:`~panovocc_cli.io.poses.frame_poses`: NICE-SLAM line i is frame i, TUM timestamps matched to the
    frame indices); the pose file the map was made with is not read. Order of writes (:meth:`.rpu.
    ReversibleMemory.save`): the revised frames' delta records appended to the log, then ``memory.npz`` and
    the snapshot index, then the COMMIT record (the commit point), then poses.txt, prediction.npz, map.ply.
    A run that fails or is killed before the commit leaves records the next opening cuts off: the map is as
    it was.
    """
    if not isinstance(cfg, ReviseConfig):
        if poses_path is None:
            raise ValueError("run_revise needs a ReviseConfig or (out, poses_path)")
        cfg = ReviseConfig(out=str(cfg), poses=str(poses_path), progress=progress)
    cfg = validate_config(cfg)
    out = Path(cfg.out)
    with _writer_lock(out):
        return _run_revise(out, cfg.poses, cfg.progress)


def run_compact(out: str | Path) -> dict:
    """Rewrite a map folder's delta log so it holds only the kept deltas (:meth:`.rpu.ReversibleMemory.compact`):
    the records of a revised frame's earlier poses and of removed frames are dropped; the memory, its
    exports and every kept record's bytes stay as they are. A map whose log holds no dead record is left
    as it is. Returns {"frames", "before", "after" (log bytes), "shards" (files after)}."""
    out = Path(out)
    with _writer_lock(out):
        _require_deltas(out)
        mapper = Mapper.load(out)
        try:
            before, after = mapper.compact()
            frames = len(mapper)
        finally:
            mapper.close()
    return {"frames": frames, "before": before, "after": after, "shards": len(mapstore.shard_ids(out))}


REVISE_GSC_BLOCK = 128
"""GSC cube side of ``revise``'s export (``map``'s is :data:`~..semantics.gsc.BLOCK`, 64): the same labels, about
a quarter less CPU on the building (fewer halo voxels consolidated twice) for a larger working set, which
``map``'s peak (at most 1.5x the memory held) has no room for; ``revise``'s peak is the loaded memory's
plus the save's and the export's (docs/mapping.md "Building revise, fourth pass")."""


def _run_revise(out: Path, poses_path, progress: bool) -> dict:
    cfg = load_config(out)
    n_seq = read_meta(cfg.seq).frames
    new_poses = frame_poses(poses_path, n_seq)  # map --poses's reader: TUM lines matched to frames by timestamp
    _require_deltas(out)
    mapper = Mapper.load(out)
    try:
        k, ids = len(mapper), mapper.frame_ids
        want = [int(i) for i in frame_ids(cfg.frames, n_seq)]  # --frames: the range the map was made of
        if k < len(want) and ids == want[:k]:
            raise PanovoccError(f"the map is incomplete ({k} of {len(want)} frames; run map --resume first)", out)
        if ids != want:
            raise PanovoccError(f"sequence now has {n_seq} frames, the map has {k}", cfg.seq)
        if len(new_poses) != n_seq:
            raise PanovoccError(f"{len(new_poses)} poses, the sequence has {n_seq} frames", poses_path)
        seq = _open_sequence(dataclasses.replace(cfg, poses=str(poses_path)), new_poses)
        reader = SequenceFrames(seq).read  # no segmenter: the deltas keep its observations
        mapper.frame_source = reader
        changed = [i for i in ids if not np.array_equal(new_poses[i], mapper.pose(i))]
        incremental = export_is_current(out, mapper)  # prediction.npz is the loaded memory's export
        if incremental:
            mapper.memory.track_changes()  # the blocks the swaps reach: the GSC cubes to label again
        from tqdm import tqdm

        t0 = time.perf_counter()
        # until the save's COMMIT record the map is as it was: a failure leaves records that the next
        # opening cuts off
        try:
            bar = tqdm(total=len(changed), desc="revise", unit="frame", file=sys.stderr, disable=not progress)
            w0, c0 = time.perf_counter(), time.process_time()
            # frame i + 1 is read while frame i is revised, and its delta computed while frame i's is swapped in
            mapper.revise_many(((i, new_poses[i], frame) for i, frame in prefetched(reader, changed)),
                               done=lambda _: bar.update(1))
            mapper.flush()  # the last record on disk: the revisions' cost as a run pays it (no load, no export)
            revisions = {"revise_s": time.perf_counter() - w0, "revise_cpu_s": time.process_time() - c0}
            bar.close()
            # the memory no longer changes: memory.npz is streamed from it on the writer thread (then the
            # commit, then poses.txt) while this thread exports it; close() waits for the commit and
            # re-raises a failed write. The grid and PLY are written after the commit, as before.
            mapper.save(out, background=FROZEN)
            try:
                if incremental:  # only the voxels within the GSC's reach of a changed block; the same labels
                    ex = mapper.export(read_grid(out / "prediction.npz"),
                                       changed_blocks=mapper.memory.changed_blocks(), block=REVISE_GSC_BLOCK)
                else:
                    ex = mapper.export(block=REVISE_GSC_BLOCK)
            finally:
                mapper.close()
        except BaseException:
            mapper._rpu.rollback()
            raise
    finally:
        mapper.close()
    summary = {"frames": k, "revised": len(changed), "seconds": time.perf_counter() - t0,
               "incremental_export": incremental, **revisions}
    summary.update(write_exports(out, mapper, cfg.semantic.ply_color, ex))
    record_export(out, mapper)
    return summary
