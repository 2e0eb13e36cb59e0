"""The Reversible Persistent Update (RPU): the memory is the exact integer sum of per-frame deltas that are
kept, so any frame can be taken out again and put back under a new pose.

Everything the method needs is here:

* :class:`DeltaStore` keeps each frame's sparse :class:`~.memory.FrameDelta` (one :class:`~.memory.Delta`
  per contributor) and the pose it was computed under, in RAM (``folder=None``) or as files in ``folder/deltas/`` (written on a background thread);
* :class:`ReversibleMemory` couples a :class:`~.memory.VoxelMemory` with a store: ``keep`` (add a frame),
  ``revise`` (subtract the kept delta, re-add the recomputed one), ``remove`` (subtract it, forget it),
  ``save`` / ``load`` (persist the memory and the deltas).

Integer addition is exact and order-independent, so after any sequence of these operations the memory
equals, bit for bit, the sum of the deltas it keeps: revising frame i equals having used the final pose
from the start, and removing frame i equals never having added it (tests/mapping/test_mapper.py).

Crash safety of a folder (file formats: :mod:`panovocc_cli.io.mapstore`). ``memory.npz`` is the commit
point; it lists the committed frames and their poses. A delta of a frame that is not committed is written
under its final name (a later run recomputes it anyway). A delta that replaces a committed one is staged
as ``NNNNNN.npz.new`` and a removed frame's file stays until the next commit; after ``memory.npz`` is
written the staged files are renamed and the removed ones deleted. :meth:`ReversibleMemory.load` rolls a
staged delta forward when ``memory.npz`` already holds its pose (killed between commit and rename) and
discards it otherwise; a delta is checked against its committed pose whenever it is read back.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..io import mapstore
from .memory import Delta, FrameDelta, VoxelMemory


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

    def wait(self):
        if self._pending is not None:
            p, self._pending = self._pending, None
            p.result()

    def close(self):
        self.wait()
        self._pool.shutdown()


def _as_frame_delta(delta: "Delta | FrameDelta") -> FrameDelta:
    return delta if isinstance(delta, FrameDelta) else FrameDelta((delta,))


def _compact_parts(delta: FrameDelta) -> list:
    """A frame delta's parts with channels in the smallest integer types (what a RAM store keeps; read
    back as int64)."""
    return [(p.keys.copy(), {name: mapstore._compact(arr) for name, arr in p.channels.items()}) for p in delta.parts]


class DeltaStore:
    """Each kept frame's delta and pose, by frame id.

    Parameters
    ----------
    folder : path or None
        None: deltas are kept in RAM (channels in their smallest integer type, keys as int64). A folder:
        deltas are files ``folder/deltas/NNNNNN.npz`` (:mod:`panovocc_cli.io.mapstore`) and only poses
        stay in RAM.
    committed : dict frame id -> (4, 4) pose, the frames ``folder/memory.npz`` already holds (from
        :meth:`ReversibleMemory.load`)
    """

    def __init__(self, folder: str | Path | None = None, committed: dict | None = None):
        self.folder = None if folder is None else Path(folder)
        self.poses: dict[int, np.ndarray] = {k: np.asarray(v, np.float64) for k, v in (committed or {}).items()}
        self._ram: dict[int, tuple[np.ndarray, dict]] = {}
        self._committed = dict(self.poses)
        self._staged: dict[int, Path] = {}
        self._doomed: set[int] = set()  # committed files to delete at the next commit
        self._writer = None
        if self.folder is not None:
            (self.folder / mapstore.DELTAS_DIR).mkdir(parents=True, exist_ok=True)

    # -- queries ---------------------------------------------------------------------------------
    def __contains__(self, frame_id: int) -> bool:
        return int(frame_id) in self.poses

    def __len__(self) -> int:
        return len(self.poses)

    def ids(self) -> list[int]:
        """Kept frame ids, ascending."""
        return sorted(self.poses)

    def get(self, frame_id: int) -> FrameDelta:
        """The kept delta of ``frame_id`` (int64 channels)."""
        fid = int(frame_id)
        if fid not in self.poses:
            raise PanovoccError(f"frame {fid} is not in the map")
        self.flush()
        return self._read(fid, self.folder, self._ram, self._staged)

    def _read(self, fid: int, folder: Path | None, ram: dict, staged: dict) -> FrameDelta:
        if folder is None:
            return FrameDelta(tuple(Delta(keys, {k: v.astype(np.int64) for k, v in ch.items()}) for keys, ch in ram[fid]))
        path = staged.get(fid, mapstore.delta_path(folder, fid))
        parts, T = mapstore.read_delta(path)
        if not np.array_equal(T, self.poses[fid]):
            raise PanovoccError(f"delta of frame {fid} was computed under another pose than memory.npz holds "
                                "(the map folder was changed by another process)", path)
        return FrameDelta(tuple(Delta(keys, ch) for keys, ch in parts))

    # -- changes ---------------------------------------------------------------------------------
    def put(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray) -> None:
        """Keep ``delta`` (computed under ``T_world_cam`` (4, 4)) as frame ``frame_id``'s, replacing any."""
        fid = int(frame_id)
        T = np.array(T_world_cam, np.float64)
        delta = _as_frame_delta(delta)
        self.poses[fid] = T
        self._doomed.discard(fid)
        if self.folder is None:
            self._ram[fid] = _compact_parts(delta)
            return
        path = mapstore.delta_path(self.folder, fid)
        if fid in self._committed:
            path = mapstore.staged_path(path)
            self._staged[fid] = path
        self._submit(mapstore.write_delta, path, [(p.keys, p.channels) for p in delta.parts], T)

    def drop(self, frame_id: int) -> None:
        """Forget frame ``frame_id`` (a committed file is deleted at the next commit)."""
        fid = int(frame_id)
        if fid not in self.poses:
            raise PanovoccError(f"frame {fid} is not in the map")
        del self.poses[fid]
        if self.folder is None:
            del self._ram[fid]
            return
        self.flush()
        staged = self._staged.pop(fid, None)
        if staged is not None:
            staged.unlink(missing_ok=True)
        if fid in self._committed:
            self._doomed.add(fid)
        else:
            mapstore.delta_path(self.folder, fid).unlink(missing_ok=True)

    def _submit(self, fn, *args) -> None:
        """Run ``fn(*args)`` on the writer thread (started on first use), after the writes queued before it."""
        if self._writer is None:
            self._writer = _BackgroundWriter()
        self._writer.submit(fn, *args)

    def flush(self) -> None:
        """Wait for the pending delta write (re-raises its error)."""
        if self._writer is not None:
            self._writer.wait()

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    # -- persistence -----------------------------------------------------------------------------
    def commit(self, folder: str | Path, write_memory, background: bool = False) -> None:
        """Make ``folder`` hold every kept delta, with ``write_memory()`` (which writes ``memory.npz``,
        the commit point) called once all delta files are on disk. A store kept in RAM or in another
        folder moves into ``folder`` (its RAM is freed; later changes go there).

        ``background``: ``write_memory`` and the renames after it run on the delta writer thread, after
        the delta writes queued before them (so in the same order); :meth:`flush` or :meth:`close` waits
        for them and re-raises their error."""
        folder = Path(folder)
        if self.folder is None or self.folder.resolve() != folder.resolve():
            self._move_to(folder)
        self.flush()
        staged, doomed = sorted(self._staged.items()), sorted(self._doomed)

        def finish():
            write_memory()
            for fid, tmp in staged:
                tmp.replace(mapstore.delta_path(folder, fid))
            for fid in doomed:
                mapstore.delta_path(folder, fid).unlink(missing_ok=True)

        if background:
            self._submit(finish)
        else:
            finish()
        self._staged.clear()
        self._doomed.clear()
        self._committed = dict(self.poses)

    def _move_to(self, folder: Path) -> None:
        """Write every kept delta into ``folder`` (staged where its memory.npz holds that frame)."""
        committed = _committed_poses(folder) if (folder / mapstore.MEMORY_NAME).is_file() else {}
        self.flush()
        old = (self.folder, self._ram, self._staged)
        self.folder, self._ram, self._staged = folder, {}, {}
        self._committed = committed
        self._doomed = set(committed) - set(self.poses)
        (folder / mapstore.DELTAS_DIR).mkdir(parents=True, exist_ok=True)
        for fid in self.ids():
            self.put(fid, self._read(fid, *old), self.poses[fid])
            if old[0] is None:
                del old[1][fid]  # free the RAM copy as soon as its file is queued
        self.flush()


def _committed_poses(folder: Path) -> dict:
    """Frame id -> pose of the frames ``folder/memory.npz`` holds (reads only the small arrays)."""
    path = folder / mapstore.MEMORY_NAME
    try:
        with np.load(path, allow_pickle=False) as z:
            poses = np.asarray(z["poses"], np.float64)
            done = int(z["frames_done"])
            ids = np.asarray(z["frame_ids"], np.int64) if "frame_ids" in z.files else None
    except Exception as e:  # noqa: BLE001
        raise PanovoccError(f"cannot read memory ({type(e).__name__}: {e})", path) from None
    return _pose_table(poses, done, ids)


def _pose_table(poses: np.ndarray, frames_done: int, ids: np.ndarray | None) -> dict:
    if ids is None:  # frames 0..frames_done-1 (a map run's checkpoint may list the poses of all its frames)
        ids = np.arange(min(frames_done, len(poses)))
        poses = poses[: len(ids)]
    return {int(i): np.asarray(T, np.float64) for i, T in zip(ids, poses)}


class ReversibleMemory:
    """A voxel memory that is always the exact sum of the deltas its store keeps.

    Parameters
    ----------
    memory : VoxelMemory, empty or holding exactly the sum of ``store``'s deltas
    store : DeltaStore
    """

    def __init__(self, memory: VoxelMemory, store: DeltaStore):
        self.memory = memory
        self.store = store

    def keep(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray) -> None:
        """Add a new frame's delta (computed under ``T_world_cam``) to the memory and keep it."""
        if frame_id in self.store:
            raise PanovoccError(f"frame {frame_id} is already in the map (revise or remove it)")
        self.memory.add(delta, +1)
        self.store.put(frame_id, delta, T_world_cam)

    def revise(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray) -> None:
        """Subtract the kept delta of ``frame_id`` and add ``delta`` (recomputed under ``T_world_cam``)."""
        old = self.store.get(frame_id)
        self.memory.add(old, -1)
        self.memory.add(delta, +1)
        self.store.put(frame_id, delta, T_world_cam)

    def remove(self, frame_id: int) -> None:
        """Subtract the kept delta of ``frame_id`` and forget the frame."""
        old = self.store.get(frame_id)
        self.memory.add(old, -1)
        self.store.drop(frame_id)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Kept frame ids (n,) int64 ascending and their poses (n, 4, 4) float64."""
        ids = self.store.ids()
        poses = np.stack([self.store.poses[i] for i in ids]) if ids else np.zeros((0, 4, 4))
        return np.asarray(ids, np.int64), poses

    def save(self, folder: str | Path, background: bool = False) -> None:
        """Persist into ``folder``: every kept delta, then ``memory.npz`` (the commit point).

        ``memory.npz`` lists the kept frames' poses in id order; their ids are stored too unless they are
        ``0..n-1`` (a map run's file keeps its historical bytes). ``background``: the memory file is
        written on the delta writer thread (:meth:`DeltaStore.commit`) from the memory as it is now."""
        ids, poses = self.poses()
        plain = np.array_equal(ids, np.arange(len(ids)))
        arrays = self.memory.to_arrays(sparse=True)  # now: the memory may change while a background write runs

        def write():
            mapstore.write_memory(folder, arrays, len(ids), poses, None if plain else ids)

        Path(folder).mkdir(parents=True, exist_ok=True)
        self.store.commit(folder, write, background)

    @classmethod
    def load(cls, folder: str | Path) -> "ReversibleMemory":
        """Reopen a saved folder; the deltas stay on disk there (read back when revised or removed).

        Staged deltas left by a killed process are rolled forward or discarded (module docstring)."""
        folder = Path(folder)
        arrays, done, poses, ids = mapstore.read_memory(folder, sparse=True)
        memory = VoxelMemory.from_arrays(arrays, folder / mapstore.MEMORY_NAME)
        committed = _pose_table(poses, done, ids)
        settle_staged(folder, committed)
        return cls(memory, DeltaStore(folder, committed))

    def close(self) -> None:
        self.store.close()


def settle_staged(folder: Path, committed: dict) -> None:
    """Roll staged deltas forward when ``memory.npz`` already holds their pose, else delete them."""
    for tmp in sorted((Path(folder) / mapstore.DELTAS_DIR).glob("*.npz" + mapstore.STAGED_SUFFIX)):
        try:
            fid = int(tmp.name.split(".")[0])
            _, T = mapstore.read_delta(tmp)
            ok = fid in committed and np.array_equal(T, committed[fid])
        except (PanovoccError, ValueError):
            ok = False
        if ok:
            tmp.replace(mapstore.delta_path(folder, fid))
        else:
            tmp.unlink()
