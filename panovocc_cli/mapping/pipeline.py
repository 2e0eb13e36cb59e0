"""``run_map`` and ``run_revise``: a sequence in, a persistent reversible memory and its exports out.

Output folder (format details in docs/mapping.md)::

    OUT/config.json        resolved MapConfig (SEQ, poses file, every parameter)
    OUT/memory.npz         the memory: non-zero voxels in key order, integer channels, frames_done, poses
    OUT/deltas/NNNNNN.npz  each frame's sparse delta (keys, channels, the pose it was computed under)
    OUT/poses.txt          the poses the retained deltas were computed under (NICE-SLAM form)
    OUT/prediction.npz     CONVENTIONS.md grid: occupied voxels carry a vocabulary class (1..C) or 254,
                           0 free, 255 unobserved; class_names = ["empty"] + vocabulary
    OUT/map.ply            occupied voxel centres, coloured by class (or mean RGB / height)

Two contributors produce each frame's delta: the geometry (PSVF support, free space) and, unless
the segmenter is ``none``, the semantics (:mod:`.semantic`: segmenter evidence, colour and normal
sums). The memory is the sum of the retained deltas; ``revise`` subtracts a frame's old delta and adds
the one recomputed under its new pose (integers, so exact, semantics included).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence as Seq

import numpy as np

from ..errors import PanovoccError
from ..io.atomic import write_text
from ..io.grid import write_grid
from ..io.npz import write_npz
from ..io.poses import read_poses, write_poses
from ..io.sequence import Sequence, frame_stem
from .contributors import geometry_delta
from .params import GeometryParams, OccupancyParams
from .export import classify, memory_to_grid, occupied_points_and_colors, write_ply_points
from .memory import GEOMETRY_CHANNELS, ChannelSpec, Delta, VoxelMemory, merge_deltas
from .semantic import SemanticParams

CONFIG_NAME = "config.json"
MEMORY_NAME = "memory.npz"
FORMAT_VERSION = 3  # 3: footprint-fitted surfels, N = frames with a measurement in the voxel, occupancy rule
# (2: semantic section; a version-1 config is a geometry-only map)


@dataclass
class MapConfig:
    """Everything ``panovocc map`` needs; saved resolved as ``OUT/config.json``."""

    seq: str  # sequence folder (CONVENTIONS.md layout)
    out: str  # output folder
    poses: str | None = None  # pose file; None = SEQ/poses.txt
    checkpoint_every: int = 25  # frames between memory checkpoints (0 = only at the end)
    geometry: GeometryParams = field(default_factory=GeometryParams)
    occupancy: OccupancyParams = field(default_factory=OccupancyParams)
    stride: int = 0  # requested stride; 0 = auto (max(1, W // 256)); the resolved one is geometry.stride
    # segmenter, vocabulary, GSC; the default "auto" = simulated when the sequence has labels, else none
    semantic: SemanticParams = field(default_factory=SemanticParams)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["format_version"] = FORMAT_VERSION
        return d

    @classmethod
    def from_json(cls, d: dict, where) -> "MapConfig":
        try:
            g = GeometryParams(**d["geometry"])
            o = OccupancyParams(**d["occupancy"])
            s = SemanticParams.from_json(d.get("semantic"))
            return cls(seq=d["seq"], out=d["out"], poses=d.get("poses"), checkpoint_every=int(d["checkpoint_every"]),
                       geometry=g, occupancy=o, stride=int(d.get("stride", 0)), semantic=s)
        except (KeyError, TypeError, ValueError) as e:
            raise PanovoccError(f"not a panovocc map config ({type(e).__name__}: {e})", where) from None


def resolve_semantic(p: SemanticParams, seq: Sequence) -> SemanticParams:
    """:func:`semantic.resolve` with the Python API's lenient ``auto``: simulated when the sequence has
    labels, else ``none`` (geometry only). The ``map`` command refuses an unlabelled sequence without an
    explicit ``--segmenter`` instead (see cli/map_cmds.py)."""
    from .semantic import SEGMENTER_AUTO, SEGMENTER_NONE, resolve as resolve_sem

    if p.segmenter.strip() == SEGMENTER_AUTO and not seq.has_labels:
        p = dataclasses.replace(p, segmenter=SEGMENTER_NONE)
    return resolve_sem(p, seq)


def auto_stride(width: int) -> int:
    """Default kernel stride for an ERP ``width``: 256 samples around the panorama (4 at 1024)."""
    return max(1, width // 256)


# ---------------------------------------------------------------------------------------------
# Contributors


@dataclass
class Frame:
    """One frame handed to contributors; images are read on first use."""

    seq: Sequence
    index: int
    T_world_cam: np.ndarray  # (4, 4) float64
    _depth: np.ndarray | None = None

    @property
    def depth(self) -> np.ndarray:
        """(H, W) float32 metres, radial, 0 = invalid."""
        if self._depth is None:
            self._depth = self.seq.depth(self.index)
        return self._depth

    @property
    def rgb(self) -> np.ndarray:
        """(H, W, 3) uint8."""
        return self.seq.rgb(self.index)


@dataclass
class Contributor:
    """A named per-frame delta producer: ``fn(frame) -> Delta`` over ``channels``."""

    name: str
    channels: tuple
    fn: Callable[[Frame], Delta]


def geometry_contributor(params: GeometryParams) -> Contributor:
    return Contributor("geometry", GEOMETRY_CHANNELS, lambda fr: geometry_delta(fr.depth, fr.T_world_cam, params))


def semantic_contributor(params: SemanticParams, geometry: GeometryParams, width: int) -> Contributor:
    """The semantic contributor of a resolved :class:`SemanticParams` (segmenter built once, rays cached)."""
    from ..geometry.erp import ray_directions
    from ..semantics.segmenter import make_segmenter
    from .semantic import semantic_channels, semantic_frame

    seg = make_segmenter(params.segmenter, seed=int(params.seed), noise=float(params.noise))
    vocab = list(params.vocab)
    rays = ray_directions(width, width // 2)

    def fn(frame: Frame) -> Delta:
        return semantic_frame(frame, seg, vocab, geometry.voxel_size, params.weights, geometry.min_range,
                              geometry.max_range, rays)

    return Contributor("semantic", semantic_channels(len(vocab)), fn)


def build_contributors(cfg: MapConfig, seq: Sequence) -> list[Contributor]:
    """Contributors of a resolved config: geometry, then semantics unless the segmenter is ``none``."""
    out = [geometry_contributor(cfg.geometry)]
    if cfg.semantic.enabled:
        out.append(semantic_contributor(cfg.semantic, cfg.geometry, seq.meta.width))
    return out


def frame_delta(frame: Frame, contributors: Seq[Contributor]) -> Delta:
    """Merged delta of all contributors for one frame."""
    return merge_deltas([c.fn(frame) for c in contributors])


def memory_channels(contributors: Seq[Contributor]) -> list[ChannelSpec]:
    return [s for c in contributors for s in c.channels]


# ---------------------------------------------------------------------------------------------
# Delta and memory files


def _compact(a: np.ndarray) -> np.ndarray:
    """Smallest signed integer dtype holding ``a`` (deterministic; read back as int64)."""
    if a.size == 0:
        return a.astype(np.int8)
    lo, hi = int(a.min()), int(a.max())
    for dt in (np.int8, np.int16, np.int32):
        if np.iinfo(dt).min <= lo and hi <= np.iinfo(dt).max:
            return a.astype(dt)
    return a


def delta_path(out: Path, i: int) -> Path:
    return out / "deltas" / f"{frame_stem(i)}.npz"


def write_delta(path: Path, delta: Delta, T_world_cam: np.ndarray) -> None:
    """Keys are stored as differences (first key, then gaps): sorted keys compress to almost nothing."""
    arrays = {"keys_diff": np.diff(delta.keys, prepend=np.int64(0)), "T_world_cam": np.asarray(T_world_cam, np.float64)}
    for name, arr in delta.channels.items():
        arrays[f"ch_{name}"] = _compact(arr)
    write_npz(path, arrays, compresslevel=1)


def read_delta(path: Path) -> tuple[Delta, np.ndarray]:
    if not path.is_file():
        raise PanovoccError("delta file missing (the output folder is incomplete)", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = np.cumsum(z["keys_diff"].astype(np.int64))
            ch = {k[3:]: z[k].astype(np.int64) for k in z.files if k.startswith("ch_")}
            T = z["T_world_cam"]
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same failure
        raise PanovoccError(f"cannot read delta ({type(e).__name__}: {e})", path) from None
    return Delta(keys, ch), T


def save_memory(out: Path, mem: VoxelMemory, frames_done: int, poses: np.ndarray) -> None:
    arrays = mem.to_arrays()
    arrays["frames_done"] = np.int64(frames_done)
    arrays["poses"] = np.asarray(poses, np.float64)
    write_npz(out / MEMORY_NAME, arrays)


def load_memory(out: str | Path) -> tuple[VoxelMemory, int, np.ndarray]:
    """Reload ``OUT/memory.npz``: (memory, frames_done, poses (N, 4, 4) float64)."""
    path = Path(out) / MEMORY_NAME
    if not path.is_file():
        raise PanovoccError("memory.npz not found (not a panovocc map output, or the run stopped before "
                            "its first checkpoint)", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as e:  # noqa: BLE001
        raise PanovoccError(f"cannot read memory ({type(e).__name__}: {e})", path) from None
    mem = VoxelMemory.from_arrays(arrays, path)
    return mem, int(arrays["frames_done"]), arrays["poses"]


def load_config(out: str | Path) -> MapConfig:
    path = Path(out) / CONFIG_NAME
    if not path.is_file():
        raise PanovoccError("config.json not found (not a panovocc map output folder)", path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise PanovoccError(f"invalid JSON ({e.msg})", path) from None
    return MapConfig.from_json(d, path)


# ---------------------------------------------------------------------------------------------
# Exports


def export(out: Path, mem: VoxelMemory, occ: OccupancyParams, sem: SemanticParams | None = None) -> dict:
    """Write prediction.npz and map.ply; return counts of occupied / free / classed voxels.

    The occupied set comes from the geometry alone; with semantics, each occupied voxel is labelled by
    :func:`semantic.label_occupied` (GSC or raw argmax, bounded nearest-evidence transfer), -1 -> 254.
    map.ply colours (``sem.ply_color``): ``class`` = class colour (grey for 254), ``rgb`` = mean pixel
    colour (grey where no pixel fell in the voxel), ``height``; without semantic channels, height.
    """
    from .semantic import UNCLASSED_COLOR, apply_labels, class_colors, label_occupied

    sem = sem or SemanticParams(segmenter="none", vocab=[])
    keys, ch = mem.nonzero()
    grid, occ_keys = memory_to_grid(keys, ch, mem.voxel_size, occ)
    pos = np.searchsorted(keys, occ_keys)
    summary = {"occupied": int(len(occ_keys)), "free": int((grid.labels == 0).sum())}
    labels = None
    if sem.enabled and "E" in ch:
        _, _, g = classify(ch["A"], ch["N"], ch["F"], ch["O"], occ)
        sub = {k: ch[k][pos] for k in ("E", "S", "rgb_sum", "normal_sum", "count")}
        labels = label_occupied(occ_keys, sub, g[pos], sem)
        grid = apply_labels(grid, occ_keys, labels, sem.vocab)
        summary["classed"] = int((labels >= 0).sum())
    write_grid(out / "prediction.npz", grid)
    pts, cols = occupied_points_and_colors(occ_keys, mem.voxel_size, None)
    if sem.ply_color == "class" and labels is not None:
        cols = class_colors(labels, sem.vocab)
    elif sem.ply_color == "rgb" and "rgb_sum" in ch:
        cnt = ch["count"][pos, :1]
        rgb = np.clip(np.rint(ch["rgb_sum"][pos] / np.maximum(cnt, 1)), 0, 255).astype(np.uint8)
        cols = np.where(cnt > 0, rgb, np.array(UNCLASSED_COLOR, np.uint8))
    write_ply_points(out / "map.ply", pts, cols)
    return summary


class _BackgroundWriter:
    """Writes delta files on one worker thread (zlib releases the GIL) while the next frame is mapped.

    At most one write is pending; ``wait`` re-raises a failed write."""

    def __init__(self):
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=1)
        self._pending = None

    def submit(self, fn, *args):
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def close(self):
        self.wait()
        self._pool.shutdown()

    def wait(self):
        if self._pending is not None:
            p, self._pending = self._pending, None
            p.result()


# ---------------------------------------------------------------------------------------------
# map


def _open_sequence(cfg: MapConfig) -> Sequence:
    seq = Sequence(cfg.seq, cfg.poses)
    if seq.meta.camera != "erp":
        raise PanovoccError(f"camera {seq.meta.camera!r}: the mapper supports ERP sequences only",
                            Path(cfg.seq) / "meta.json")
    if len(seq) == 0:
        raise PanovoccError("sequence has no frames", Path(cfg.seq) / "meta.json")
    return seq


def resolve(cfg: MapConfig, width: int) -> MapConfig:
    """Fill the automatic stride and check parameter ranges."""
    g = cfg.geometry
    stride = cfg.stride if cfg.stride > 0 else auto_stride(width)
    if cfg.stride < 0:
        raise PanovoccError(f"--stride must be >= 0 (0 = auto), got {cfg.stride}")
    if not (g.voxel_size > 0):
        raise PanovoccError(f"--voxel-size must be positive, got {g.voxel_size}")
    if g.kernel not in ("psvf", "point"):
        raise PanovoccError(f"--kernel must be psvf or point, got {g.kernel!r}")
    if cfg.occupancy.rule not in ("frequency", "score"):
        raise PanovoccError(f"--rule must be frequency or score, got {cfg.occupancy.rule!r}")
    if g.radial not in ("fit", "model"):
        raise PanovoccError(f"radial must be fit or model, got {g.radial!r}")
    if cfg.checkpoint_every < 0:
        raise PanovoccError(f"--checkpoint-every must be >= 0, got {cfg.checkpoint_every}")
    return dataclasses.replace(cfg, geometry=dataclasses.replace(g, stride=stride),
                               seq=str(Path(cfg.seq).resolve()), out=str(Path(cfg.out).resolve()),
                               poses=None if cfg.poses is None else str(Path(cfg.poses).resolve()))


_OUTPUTS = (CONFIG_NAME, MEMORY_NAME, "poses.txt", "prediction.npz", "map.ply")


def run_map(cfg: MapConfig | None = None, resume_out: str | Path | None = None, overwrite: bool = False,
            progress: bool = True, stop_after: int | None = None,
            contributors: Seq[Contributor] | None = None) -> dict:
    """Map a sequence (or resume an interrupted run in ``resume_out``).

    Parameters
    ----------
    cfg : MapConfig for a new run (ignored when resuming)
    resume_out : output folder of an interrupted run; its config.json supplies everything else
    overwrite : replace an existing map output in ``cfg.out``
    stop_after : stop after this many frames as if killed there (no final save; tests of ``--resume``)
    contributors : per-frame delta producers; default = the geometry contributor alone

    Returns
    -------
    summary : dict (frames, occupied, free, ms_per_frame, ...)
    """
    if resume_out is not None:
        out = Path(resume_out)
        cfg = load_config(out)
        seq = _open_sequence(cfg)
        contributors = contributors or build_contributors(cfg, seq)
        if (out / MEMORY_NAME).is_file():
            mem, start, saved_poses = load_memory(out)
            if len(saved_poses) != len(seq) or not np.array_equal(saved_poses, seq.poses):
                raise PanovoccError("the sequence's poses changed since the run started (use revise)", out)
        else:
            mem, start = VoxelMemory(cfg.geometry.voxel_size, memory_channels(contributors)), 0
    else:
        if cfg is None:
            raise ValueError("run_map needs a config or resume_out")
        seq = _open_sequence(cfg)
        cfg = resolve(cfg, seq.meta.width)
        cfg = dataclasses.replace(cfg, semantic=resolve_semantic(cfg.semantic, seq))
        if contributors is None:
            contributors = build_contributors(cfg, seq)  # builds the segmenter: fails before any file is written
        out = Path(cfg.out)
        if out.exists() and not out.is_dir():
            raise PanovoccError("output path exists and is not a folder", out)
        if (out / CONFIG_NAME).exists():
            if not overwrite:
                raise PanovoccError("already holds a map (use --resume to continue it, --overwrite to start over)",
                                    out)
            for name in _OUTPUTS:
                (out / name).unlink(missing_ok=True)
            shutil.rmtree(out / "deltas", ignore_errors=True)
        out.mkdir(parents=True, exist_ok=True)
        write_text(out / CONFIG_NAME, json.dumps(cfg.to_json(), indent=2) + "\n")
        write_poses(out / "poses.txt", seq.poses)
        mem, start = VoxelMemory(cfg.geometry.voxel_size, memory_channels(contributors)), 0
    n = len(seq)
    end = n if stop_after is None else min(n, stop_after)
    (out / "deltas").mkdir(exist_ok=True)
    from tqdm import tqdm

    t0 = time.perf_counter()
    t_compute = 0.0
    writer = _BackgroundWriter()
    bar = tqdm(range(start, end), desc="map", unit="frame", file=sys.stderr, disable=not progress,
               initial=start, total=n)
    for i in bar:
        frame = Frame(seq, i, seq.poses[i])
        frame.depth  # read before timing the update
        tc = time.perf_counter()
        delta = frame_delta(frame, contributors)
        mem.add(delta)
        t_compute += time.perf_counter() - tc
        writer.submit(write_delta, delta_path(out, i), delta, seq.poses[i])
        done = i + 1
        if cfg.checkpoint_every and done % cfg.checkpoint_every == 0 and done < n:
            writer.wait()  # a checkpoint may only cover deltas already on disk
            save_memory(out, mem, done, seq.poses)
    writer.close()
    bar.close()
    done = end
    wall = time.perf_counter() - t0
    steps = max(end - start, 1)
    summary = {"frames": n, "integrated": end - start, "ms_per_frame": 1e3 * wall / steps,
               "update_ms_per_frame": 1e3 * t_compute / steps, "out": str(out)}
    if done < n:
        summary.update(stopped_at=done)
        return summary
    save_memory(out, mem, n, seq.poses)
    summary.update(export(out, mem, cfg.occupancy, cfg.semantic))
    return summary


# ---------------------------------------------------------------------------------------------
# revise


def run_revise(out: str | Path, poses_path: str | Path, progress: bool = True,
               contributors: Seq[Contributor] | None = None) -> dict:
    """Re-integrate exactly the frames whose pose differs in ``poses_path``; rewrite memory and exports.

    Order of writes: new deltas to staging names, then memory.npz (the commit point, it stores the
    poses), then the staged deltas renamed in place, then poses.txt, prediction.npz, map.ply. A run
    killed after the commit is completed by the next ``revise`` (staged deltas are rolled forward).
    """
    out = Path(out)
    cfg = load_config(out)
    mem, done, old_poses = load_memory(out)
    _settle_staged(out, old_poses)
    if done != len(old_poses):
        raise PanovoccError(f"the map is incomplete ({done} of {len(old_poses)} frames; run map --resume first)", out)
    new_poses = read_poses(poses_path)
    if len(new_poses) != len(old_poses):
        raise PanovoccError(f"{len(new_poses)} poses, the map has {len(old_poses)} frames", poses_path)
    seq = Sequence(cfg.seq, cfg.poses)
    if len(seq) != len(old_poses):
        raise PanovoccError(f"sequence now has {len(seq)} frames, the map has {len(old_poses)}", cfg.seq)
    contributors = contributors or build_contributors(cfg, seq)
    changed = [i for i in range(len(new_poses)) if not np.array_equal(new_poses[i], old_poses[i])]
    from tqdm import tqdm

    t0 = time.perf_counter()
    staged = []
    for i in tqdm(changed, desc="revise", unit="frame", file=sys.stderr, disable=not progress):
        old, _ = read_delta(delta_path(out, i))
        new = frame_delta(Frame(seq, i, new_poses[i]), contributors)
        mem.add(old, -1)
        mem.add(new, +1)
        p = delta_path(out, i)
        tmp = p.with_name(p.name + ".new")
        write_delta(tmp, new, new_poses[i])
        staged.append((tmp, p))
    save_memory(out, mem, len(new_poses), new_poses)
    for tmp, p in staged:
        tmp.replace(p)
    write_poses(out / "poses.txt", new_poses)
    summary = {"frames": len(new_poses), "revised": len(changed), "seconds": time.perf_counter() - t0}
    summary.update(export(out, mem, cfg.occupancy, cfg.semantic))
    return summary


def _settle_staged(out: Path, committed_poses: np.ndarray) -> None:
    """Roll staged deltas forward when memory.npz already holds their pose, else discard them."""
    for tmp in sorted((out / "deltas").glob("*.npz.new")):
        try:
            _, T = read_delta(tmp)
            i = int(tmp.name.split(".")[0])
            ok = i < len(committed_poses) and np.array_equal(T, committed_poses[i])
        except (PanovoccError, ValueError):
            ok = False
        if ok:
            tmp.replace(out / "deltas" / tmp.name[: -len(".new")])
        else:
            tmp.unlink()
