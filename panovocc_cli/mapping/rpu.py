"""The Reversible Persistent Update (RPU): the memory is the exact integer sum of per-frame deltas that are
kept, so any frame can be taken out again and put back under a new pose.

Everything the method needs is here:

* :class:`DeltaStore` keeps each frame's sparse :class:`~.memory.FrameDelta` (one :class:`~.memory.Delta`
  per contributor) and the pose it was computed under, in RAM (``folder=None``) or as records of the
  folder's sharded delta log (:class:`panovocc_cli.io.mapstore.DeltaLog`, appended on a background thread);
* :class:`ReversibleMemory` couples a :class:`~.memory.VoxelMemory` with a store: ``keep`` (add a frame),
  ``revise`` (subtract the kept delta, re-add the recomputed one), ``remove`` (subtract it, forget it),
  ``checkpoint`` (commit the log), ``save`` / ``load`` (a memory snapshot beside the log).

Integer addition is exact and order-independent, so after any sequence of these operations the memory
equals, bit for bit, the sum of the deltas it keeps: revising frame i equals having used the final pose
from the start, and removing frame i equals never having added it (tests/mapping/test_mapper.py).

Crash safety of a folder (file formats: :mod:`panovocc_cli.io.mapstore`). The commit journal's entries
are the commit points: a checkpoint appends one (and writes nothing else, so its cost does not grow with
the run); what the folder holds is the effect of the records up to the last entry, and the tail after it
is cut off when the folder is opened (a killed run's last frames, a torn record). ``save`` writes the
memory snapshot ``memory.npz``, then ``deltas/snapshot.npz`` (where in the log the snapshot is, each
frame's record, the snapshot's SHA-256), then commits; :meth:`ReversibleMemory.load` starts from a
snapshot that matches and is committed, replaying the committed records after it, or else rebuilds the
memory from the whole log (a run killed before its end, a save that failed half-way). A delta that cannot be written (disk full, read-only folder) is
taken out of the memory again, so the memory and the store agree, and the run stops with one line.

Compaction. A revision appends its frame's new record and leaves the earlier one dead in its shard; a run
that revises as it goes (``map --poses slam``) would otherwise keep every pose a frame ever had. Once the
dead bytes of the closed shards pass half the live ones (and one shard), a commit first appends the live
records of each closed shard that is at most half live again (their payloads as they are), then commits,
deletes ``deltas/snapshot.npz`` (a checkpoint's; a save writes a new one) and then those shards. Each step
leaves a folder that opens to the same memory: before the commit the copies are an uncommitted tail; after
it, a copy replayed after its original subtracts it and adds the same delta.
Maps made before the log (one ``deltas/NNNNNN.npz`` file a frame) are read as they are.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..io import mapstore
from .memory import Delta, FrameDelta, VoxelMemory

SNAPSHOT_NAME = "snapshot.npz"  # in deltas/: the memory snapshot's place in the log
#: A commit compacts the delta log once the dead records of its closed shards pass this share of the live
#: records' bytes (and one shard): the log then stays below about (1 + this) times its live records.
COMPACT_DEAD_SHARE = 0.5
#: ... rewriting the closed shards whose live records are at most this share of their bytes.
COMPACT_LIVE_SHARE = 0.5
EVERY = "every"  # DeltaStore.commit(compact=EVERY): rewrite every shard that holds a dead record
FROZEN = "frozen"  # ReversibleMemory.save(background=FROZEN): streamed on the writer thread, the memory left as it is
LEGACY = -1  # shard number of a frame whose delta is a file of its own (maps made before the log)
REPLAY_AHEAD = 2  # records a replay decodes ahead of its adds (each a frame's decoded delta, a few MB at 512x256)


class _BackgroundWriter:
    """Runs log appends on one worker thread (Zstandard releases the GIL) while the next frame is mapped.

    At most one job is pending; ``wait`` re-raises a failed one."""

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
        try:
            self.wait()
        finally:
            self._pool.shutdown()


class DeltaWriteError(Exception):
    """A delta record could not be written: ``frame_id``, the delta that failed and the one it replaced
    (None for a new frame), so the memory can be put back as the store is (``error``: the OSError)."""

    def __init__(self, frame_id: int, delta: FrameDelta | None, old: FrameDelta | None, error: BaseException, path):
        super().__init__(str(error))
        self.frame_id, self.delta, self.old, self.error, self.path = frame_id, delta, old, error, path


def _as_frame_delta(delta: "Delta | FrameDelta") -> FrameDelta:
    return delta if isinstance(delta, FrameDelta) else FrameDelta((delta,))


def _compact_parts(delta: FrameDelta) -> list:
    """A frame delta's parts with channels in the smallest integer types (what a RAM store keeps; read
    back as int64)."""
    return [(p.keys.copy(), {name: mapstore._compact(arr) for name, arr in p.channels.items()}) for p in delta.parts]


def _frame_delta(parts, observation=None) -> FrameDelta:
    """A FrameDelta from decoded parts and observation arrays (None: none kept)."""
    obs = None
    if observation is not None:
        from ..semantics.observation import SemanticObservation

        obs = SemanticObservation.from_arrays(observation)
    return FrameDelta(tuple(Delta(keys, ch) for keys, ch in parts), obs)


def _record_delta(payload: bytes, where=None) -> FrameDelta:
    """A PUT record's payload as the FrameDelta that was put (parts and kept observation)."""
    rec = mapstore.decode_record(payload, where)
    return _frame_delta(rec.parts, rec.observation)


def _held_delta(held, where) -> FrameDelta:
    """The delta of a pending append whose write failed: as it was put, or decoded from its record once the
    writer has encoded it (the same channels and observation bit for bit: what a revision reads back)."""
    return held if isinstance(held, FrameDelta) else _record_delta(held, where)


def _record_parts(delta: FrameDelta) -> list:
    """What a PUT record stores of a frame delta's parts: (keys, channels, factors) each."""
    return [(p.keys, p.channels, p.factors) for p in delta.parts]


def _observation_arrays(delta: FrameDelta):
    return None if delta.observation is None else delta.observation.to_arrays()


def encode_record(delta: FrameDelta, T_world_cam: np.ndarray) -> bytes:
    """A PUT record's payload of a frame delta computed under ``T_world_cam``: what :class:`DeltaStore`
    appends for the frame, and what a shard worker sends back (:mod:`.shards`), byte for byte."""
    return mapstore.encode_delta(_record_parts(delta), T_world_cam, _observation_arrays(delta))


def has_store(folder: str | Path) -> bool:
    """Whether ``folder`` holds a map's deltas (a log or a memory snapshot)."""
    folder = Path(folder)
    return (folder / mapstore.MEMORY_NAME).is_file() or bool(mapstore.shard_ids(folder))


class DeltaStore:
    """Each kept frame's delta and pose, by frame id.

    Parameters
    ----------
    folder : path or None
        None: deltas are kept in RAM (channels in their smallest integer type, keys as int64). A folder:
        deltas are records of ``folder/deltas/`` (:class:`~panovocc_cli.io.mapstore.DeltaLog`) and only
        poses and record locations stay in RAM. A new store refuses a folder that already holds deltas
        (:meth:`ReversibleMemory.load` reopens one).
    """

    def __init__(self, folder: str | Path | None = None, *, _log=None, _locs=None, _poses=None):
        self.folder = None if folder is None else Path(folder)
        self.poses: dict[int, np.ndarray] = dict(_poses or {})
        self._ram: dict[int, list] = {}
        self._locs: dict[int, tuple] = dict(_locs or {})
        self._log = _log
        self._writer = None
        # the pending append: (frame id, [its delta, or its record once encoded], old delta, old pose, old location)
        self._inflight = None
        self.compactions: list[tuple[int, int, int]] = []  # each compaction's shards and bytes deleted, bytes copied
        if self.folder is not None and self._log is None:
            if has_store(self.folder):
                raise PanovoccError("already holds a map (reopen it with Mapper.load)", self.folder)
            self._log = mapstore.DeltaLog(self.folder)

    # -- queries ---------------------------------------------------------------------------------
    def __contains__(self, frame_id: int) -> bool:
        return int(frame_id) in self.poses

    def __len__(self) -> int:
        return len(self.poses)

    def ids(self) -> list[int]:
        """Kept frame ids, ascending."""
        return sorted(self.poses)

    def get(self, frame_id: int) -> FrameDelta:
        """The kept delta of ``frame_id`` (int64 channels). Waits for the writer thread only when this
        frame's record is the one being written: any other kept record is on disk already, so a revision
        reads and decodes the next frame's old delta while the last one's record is compressed (a failed
        write is reported by the next change, :meth:`ReversibleMemory._flush`)."""
        fid = int(frame_id)
        if fid not in self.poses:
            raise PanovoccError(f"frame {fid} is not in the map")
        if self._inflight is not None and self._inflight[0] == fid:
            self.flush()
        if self.folder is None:
            parts, obs = self._ram[fid]
            return FrameDelta(tuple(Delta(keys, {k: v.astype(np.int64) for k, v in ch.items()})
                                    for keys, ch in parts), obs)
        return self._read(fid, self._locs[fid])

    def _read(self, fid: int, loc) -> FrameDelta:
        if loc[0] == LEGACY:
            path = mapstore.delta_path(self.folder, fid)
            parts, T = mapstore.read_delta(path)
            obs = None
        else:
            path = mapstore.shard_path(self.folder, loc[0])
            parts, T, obs = mapstore.decode_record(self._log.read(loc), path)
        if fid in self.poses and not np.array_equal(T, self.poses[fid]):
            raise PanovoccError(f"delta of frame {fid} was computed under another pose than the map holds "
                                "(the map folder was changed by another process)", path)
        return _frame_delta(parts, obs)

    def payload(self, frame_id: int) -> bytes:
        """The PUT payload of ``frame_id``'s kept delta (:func:`encode_record`): the log record's bytes as they
        are (a merge appends them unchanged), or, for a delta kept in RAM or a file of its own, encoded."""
        fid = int(frame_id)
        if fid in self.poses and self.folder is not None and self._locs[fid][0] != LEGACY and (
                self._inflight is None or self._inflight[0] != fid):
            return self._log.read(self._locs[fid])
        return encode_record(self.get(fid), self.poses[fid])

    def nbytes(self) -> int:
        """Bytes of the kept deltas on disk (the log's live records; 0 in RAM)."""
        return sum(int(loc[2]) + mapstore.RECORD_HEADER_BYTES for loc in self._locs.values() if loc[0] != LEGACY)

    # -- changes ---------------------------------------------------------------------------------
    def put(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray,
            old: FrameDelta | None = None) -> None:
        """Keep ``delta`` (computed under ``T_world_cam`` (4, 4)) as frame ``frame_id``'s, replacing any
        (``old``: the delta it replaces, kept until the record is written, so a failed write can be undone)."""
        fid = int(frame_id)
        T = np.array(T_world_cam, np.float64)
        delta = _as_frame_delta(delta)
        if self.folder is None:
            self.poses[fid] = T
            self._ram[fid] = (_compact_parts(delta), delta.observation)
            return
        self.flush()
        held = [delta]  # the writer swaps it for its record once encoded (the delta is then freed)
        inflight = (fid, held, old, self.poses.get(fid), self._locs.get(fid))
        self.poses[fid] = T
        self._inflight = inflight
        del delta
        self._submit(self._append_put, fid, held, T)

    def _append_put(self, fid: int, held: list, T) -> None:
        """Encode ``held[0]`` (the frame's delta) and append it. The delta is dropped as soon as its record
        is made (``held[0]`` then holds the record): it is not alive beside the next frame's working set
        for the rest of that frame (up to 40 bytes a row, docs/mapping.md "The per-frame working set"); a
        failed append's undo decodes the record instead (:meth:`flush`)."""
        payload = encode_record(held[0], T)
        held[0] = payload
        self._locs[fid] = self._log.append(mapstore.PUT, fid, payload)

    def put_encoded(self, frame_id: int, payload: bytes, T_world_cam: np.ndarray) -> None:
        """Keep a new frame's delta given as its record payload (:func:`encode_record`, made elsewhere: a shard
        worker, another map's log), appended as it is; the memory's side is the caller's."""
        fid = int(frame_id)
        T = np.array(T_world_cam, np.float64)
        if self.folder is None:
            d = _record_delta(payload)
            self.poses[fid] = T
            self._ram[fid] = (_compact_parts(d), d.observation)
            return
        self.flush()
        self._inflight = (fid, None, None, self.poses.get(fid), self._locs.get(fid))
        self.poses[fid] = T
        self._submit(self._append_payload, fid, payload)

    def _append_payload(self, fid: int, payload: bytes) -> None:
        self._locs[fid] = self._log.append(mapstore.PUT, fid, payload)

    def drop(self, frame_id: int) -> None:
        """Forget frame ``frame_id`` (a DROP record; committed with the next checkpoint or save)."""
        fid = int(frame_id)
        if fid not in self.poses:
            raise PanovoccError(f"frame {fid} is not in the map")
        self.flush()
        del self.poses[fid]
        if self.folder is None:
            del self._ram[fid]
            return
        self._locs.pop(fid, None)
        self._submit(self._log.append, mapstore.DROP, fid, b"")

    def _submit(self, fn, *args) -> None:
        """Run ``fn(*args)`` on the writer thread (started on first use), after the jobs queued before it."""
        if self._writer is None:
            self._writer = _BackgroundWriter()
        self._writer.submit(fn, *args)

    def flush(self) -> None:
        """Wait for the pending append. A failed delta write puts the store back as it was before that
        frame and raises :class:`DeltaWriteError` (the memory's side is :class:`ReversibleMemory`'s)."""
        if self._writer is None:
            return
        inflight, self._inflight = self._inflight, None
        try:
            self._writer.wait()
        except OSError as e:
            if inflight is None:
                raise
            fid, held, old, old_T, old_loc = inflight
            delta = None if held is None else _held_delta(held[0], mapstore.shard_path(self.folder, self._log.shard))
            if old_T is None:
                self.poses.pop(fid, None)
                self._locs.pop(fid, None)
            else:
                self.poses[fid], self._locs[fid] = old_T, old_loc
            raise DeltaWriteError(fid, delta, old, e, mapstore.shard_path(self.folder, self._log.shard)) from None

    def close(self) -> None:
        if self._writer is not None:
            try:
                self.flush()
            finally:
                self._writer.close()
                self._writer = None

    # -- persistence -----------------------------------------------------------------------------
    def log_bytes(self) -> int:
        """Bytes of the folder's delta log (its shard files, live records and dead ones)."""
        return sum(self._log.shard_sizes().values())

    def live_bytes(self) -> dict[int, tuple[int, int]]:
        """Each shard of the log as (its bytes, the bytes of its live records), by shard number. A record is
        live while it is its frame's kept delta: a revision or a removal leaves the frame's earlier one dead."""
        sizes = self._log.shard_sizes()
        live = dict.fromkeys(sizes, 0)
        for loc in self._locs.values():
            if loc[0] != LEGACY:
                live[loc[0]] = live.get(loc[0], 0) + int(loc[2]) + mapstore.RECORD_HEADER_BYTES
        return {s: (sizes.get(s, 0), v) for s, v in sorted(live.items())}

    def compaction_victims(self, every: bool = False) -> list[int]:
        """The closed shards a compaction rewrites now: none until the dead bytes of the closed shards pass
        :data:`COMPACT_DEAD_SHARE` of the live bytes and one shard's size; then each closed shard whose live
        records are at most :data:`COMPACT_LIVE_SHARE` of its bytes (rewriting them costs at most what it
        frees). ``every``: each closed shard holding a dead byte."""
        if self.folder is None or self._log is None:
            return []
        shards = self.live_bytes()
        closed = {s: v for s, v in shards.items() if s != self._log.shard}
        if every:
            return [s for s, (size, live) in closed.items() if live < size]
        dead = sum(size - live for size, live in closed.values())
        if dead <= max(COMPACT_DEAD_SHARE * sum(live for _, live in shards.values()), mapstore.SHARD_BYTES):
            return []
        return [s for s, (size, live) in closed.items() if live <= COMPACT_LIVE_SHARE * size]

    def _rewrite(self, victims: list[int]) -> int:
        """Append the live records of ``victims`` again at the log's end (their payloads as they are, in log
        order) and point the frames at the copies; a DROP in a victim is appended again for a frame not kept
        whose earlier PUT is in a shard that stays. A failed write cuts the copies off again and the
        store is as it was (one line). Returns the bytes copied."""
        log, vs = self._log, set(victims)
        pos, old = (log.shard, log.end), dict(self._locs)
        moving = sorted((loc, fid) for fid, loc in self._locs.items() if loc[0] in vs)
        drops = {fid for s in victims for kind, fid, _ in log.headers(s) if kind == mapstore.DROP and fid not in self.poses}
        if drops:  # a DROP matters only while a shard that stays holds an earlier (dead) PUT of its frame
            stay = [s for s, (size, live) in self.live_bytes().items() if s not in vs and live < size]
            drops &= {fid for s in stay for kind, fid, _ in log.headers(s) if kind == mapstore.PUT}
        try:
            for loc, fid in moving:
                self._locs[fid] = log.append(mapstore.PUT, fid, log.read(loc))
            for fid in sorted(drops):
                log.append(mapstore.DROP, fid, b"")
        except OSError as e:
            self._locs = old
            log.cut_to(pos)
            raise PanovoccError(f"cannot compact the delta log ({e.strerror or e}); the map is as it was",
                                mapstore.shard_path(self.folder, log.shard)) from None
        return sum(int(loc[2]) + mapstore.RECORD_HEADER_BYTES for loc, _ in moving)

    def commit(self, background: bool = False, before=None, after=None, compact: bool | str = True) -> None:
        """A checkpoint: every kept delta on disk, ``before()`` (if given: the snapshot files of a save),
        then a journal entry (fsync'd), then ``after()`` (if given: what must follow the commit, a save's
        poses.txt); on the writer thread with ``background``.

        ``compact``: when the log's dead records have grown past :meth:`compaction_victims`' bound, the live
        records of the mostly dead shards are appended again first (here, before any background work) and
        the shards deleted once the commit is made; :data:`EVERY`: every shard holding a dead record (the
        current one closed first). A checkpoint that deletes shards deletes ``deltas/snapshot.npz`` before
        them (its record locations may be theirs): the next opening rebuilds the memory from the log."""
        self.flush()
        victims = []
        if compact and self.folder is not None and self._log is not None:
            if compact == EVERY:
                size, live = self.live_bytes().get(self._log.shard, (0, 0))
                if live < size:
                    self._log.roll()  # the current shard holds a dead record: rewritten too
            victims = self.compaction_victims(every=compact == EVERY)
            if victims:
                freed = sum(self._log.shard_sizes()[s] for s in victims)
                self.compactions.append((len(victims), freed, self._rewrite(victims)))

        def finish():
            if before is not None:
                before()
            self._log.commit(compact=before is not None or bool(victims))
            if victims:
                if before is None:
                    (self.folder / mapstore.DELTAS_DIR / SNAPSHOT_NAME).unlink(missing_ok=True)
                self._log.remove_shards(victims)
            if after is not None:
                after()

        if background:
            self._submit(finish)
        else:
            finish()

    def rollback(self) -> None:
        """Cut the records appended since the last commit (a failed command leaves the folder as it was)."""
        if self._writer is not None:
            try:
                self._writer.wait()
            except Exception:  # noqa: BLE001 - the failure is being handled by the caller
                pass
        self._inflight = None
        if self._log is not None:
            self._log.rollback()

    def move_to(self, folder: Path) -> None:
        """Write every kept delta into ``folder``'s new log (a RAM store, or a store of another folder)."""
        self.flush()
        old = (self.folder, dict(self._locs), self._log)
        reading = DeltaStore.__new__(DeltaStore)
        reading.folder, reading._locs, reading._log, reading.poses = old[0], old[1], old[2], self.poses
        reading._ram, reading._writer, reading._inflight = self._ram, None, None
        log = mapstore.DeltaLog(folder) if not has_store(folder) else None
        if log is None:
            raise PanovoccError("already holds a map (reopen it with Mapper.load)", folder)
        self.folder, self._log, self._locs = folder, log, {}
        for fid in self.ids():
            d = reading.get(fid)
            self._locs[fid] = log.append(mapstore.PUT, fid, encode_record(d, self.poses[fid]))
            self._ram.pop(fid, None)  # free the RAM copy as soon as its record is written
        if old[2] is not None:
            old[2].close()

    def snapshot_index(self) -> dict:
        """Where each kept frame's record is, and the log position and commit number: the arrays of
        ``deltas/snapshot.npz`` (call after :meth:`commit`)."""
        ids = np.asarray(self.ids(), np.int64)
        locs = np.asarray([self._locs[i] for i in ids], np.int64).reshape(-1, 3)
        return {"frame_ids": ids, "locations": locs, "log_end": np.asarray([self._log.shard, self._log.end], np.int64)}


def _write_snapshot_index(store: DeltaStore, memory_sha256: str) -> None:
    """``deltas/snapshot.npz``: where the kept records are and the snapshot's place in the log (call before the
    commit that makes them so), for the ``memory.npz`` of SHA-256 ``memory_sha256``."""
    from ..io.npz import write_npz

    index = store.snapshot_index()
    index["memory_sha256"] = np.array(memory_sha256)
    write_npz(store.folder / mapstore.DELTAS_DIR / SNAPSHOT_NAME, index, compresslevel=1)


def _read_snapshot(folder: Path, memory_path: Path):
    """deltas/snapshot.npz when it describes ``memory_path`` (its SHA-256 matches), else None."""
    path = folder / mapstore.DELTAS_DIR / SNAPSHOT_NAME
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            snap = {k: np.asarray(z[k]) for k in z.files}
    except Exception:  # noqa: BLE001 - an unreadable snapshot is rebuilt from the log
        return None
    if str(snap.get("memory_sha256", "")) != sha256_file(memory_path):
        return None
    return snap


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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
        self.loaded_snapshot = None  # load(): memory.npz's SHA-256 when the memory is that file's, no record after it

    def _flush(self) -> None:
        """The store's pending write; a failed delta write is undone in the memory too, then one line."""
        try:
            self.store.flush()
        except DeltaWriteError as e:
            if e.delta is not None:
                self.memory.add(e.delta, -1)
            if e.old is not None:
                self.memory.add(e.old, +1)
            err = e.error
            raise PanovoccError(f"cannot write the delta of frame {e.frame_id} "
                                f"({getattr(err, 'strerror', None) or err}); the map holds the frames before it",
                                e.path) from None

    def keep(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray) -> None:
        """Add a new frame's delta (computed under ``T_world_cam``) to the memory and keep it."""
        self._flush()
        if frame_id in self.store:
            raise PanovoccError(f"frame {frame_id} is already in the map (revise or remove it)")
        delta = _as_frame_delta(delta)
        self.memory.add(delta, +1)
        self.store.put(frame_id, delta, T_world_cam)

    def keep_encoded(self, frame_id: int, payload: bytes, T_world_cam: np.ndarray) -> None:
        """Keep a new frame's delta given as its record payload, without adding it to the memory: the caller
        adds the sum of such deltas (a sharded run's partial memories, a merge's inputs) with
        ``memory.add``, so the memory is again the exact sum of the kept deltas."""
        self._flush()
        if frame_id in self.store:
            raise PanovoccError(f"frame {frame_id} is already in the map (revise or remove it)")
        self.store.put_encoded(frame_id, payload, T_world_cam)

    def revise(self, frame_id: int, delta: "Delta | FrameDelta", T_world_cam: np.ndarray,
               old: FrameDelta | None = None) -> None:
        """Subtract the kept delta of ``frame_id`` and add ``delta`` (recomputed under ``T_world_cam``);
        ``old``: the kept delta when the caller has just read it (:meth:`DeltaStore.get`)."""
        self._flush()
        if old is None:
            old = self.store.get(frame_id)
        delta = _as_frame_delta(delta)
        self.memory.replace(old, delta)  # one pass over the union of their voxels
        self.store.put(frame_id, delta, T_world_cam, old=old)

    def remove(self, frame_id: int) -> None:
        """Subtract the kept delta of ``frame_id`` and forget the frame."""
        self._flush()
        old = self.store.get(frame_id)
        self.memory.add(old, -1)
        self.store.drop(frame_id)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Kept frame ids (n,) int64 ascending and their poses (n, 4, 4) float64."""
        ids = self.store.ids()
        poses = np.stack([self.store.poses[i] for i in ids]) if ids else np.zeros((0, 4, 4))
        return np.asarray(ids, np.int64), poses

    def checkpoint(self, background: bool = False) -> None:
        """Commit what the folder's log holds (a COMMIT record; nothing else is written)."""
        self._flush()
        if self.store.folder is None:
            raise PanovoccError("a checkpoint needs a folder (this memory keeps its deltas in RAM)")
        self.store.commit(background)

    def save(self, folder: str | Path, background: bool | str = False, after=None, compact: bool | str = True) -> None:
        """Persist into ``folder``: every kept delta and a COMMIT, then the memory snapshot ``memory.npz``
        and ``deltas/snapshot.npz``; then ``after()`` (if given), once the commit is made.

        ``memory.npz`` lists the kept frames' poses in id order; their ids are stored too unless they are
        ``0..n-1`` (a map run's file keeps its historical bytes). ``background``: the snapshot, the
        commit and ``after`` run on the writer thread from the memory as it is now; :data:`FROZEN`: on the
        writer thread too, but streamed from the memory itself (no copy): the caller promises not to change
        the memory until :meth:`close` returns (it may read it meanwhile, e.g. export it)."""
        self._flush()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        if self.store.folder is None or self.store.folder.resolve() != folder.resolve():
            self.store.move_to(folder)
        ids, poses = self.poses()
        plain = np.array_equal(ids, np.arange(len(ids)))
        # in the foreground, memory.npz is streamed from the memory a key range at a time (no copy of every
        # voxel's keys and channels, docs/mapping.md "Memory layout"); in the background it is taken now, as
        # whole arrays: the memory may change while the write runs. Both give the same bytes.
        # FROZEN streams it on the writer thread (the scan included): the memory does not change meanwhile.
        if background == FROZEN:
            arrays = None
        elif background:
            arrays = self.memory.to_arrays(sparse=True)
        else:
            arrays = self.memory.chunked()
        memory, store = self.memory, self.store

        def write():  # before the commit: a failure here leaves the folder's committed state as it was
            mapstore.write_memory(folder, memory.chunked() if arrays is None else arrays, len(ids), poses,
                                  None if plain else ids)
            _write_snapshot_index(store, sha256_file(folder / mapstore.MEMORY_NAME))

        store.commit(bool(background), before=write, after=after, compact=compact)

    def compact(self) -> tuple[int, int]:
        """Rewrite every shard of the folder's log that holds a dead record (a revised frame's earlier
        record, a removed frame's), so the log holds only the kept deltas; the memory does not change.
        Returns the log's bytes before and after. A memory loaded as ``memory.npz`` holds (no record after
        its snapshot) keeps that file: only the snapshot index is written again; else :meth:`save`."""
        self._flush()
        store = self.store
        if store.folder is None:
            raise PanovoccError("compaction needs a folder (this memory keeps its deltas in RAM)")
        shards = store.live_bytes()
        before = sum(size for size, _ in shards.values())
        if all(live == size for size, live in shards.values()):
            return before, before  # no dead record: the folder is left as it is
        if self.loaded_snapshot is None:
            self.save(store.folder, compact=EVERY)
        else:
            sha = self.loaded_snapshot
            store.commit(before=lambda: _write_snapshot_index(store, sha), compact=EVERY)
        return before, store.log_bytes()

    def rollback(self) -> None:
        """After a failed command: cut the uncommitted records (the memory object is not usable after)."""
        self.store.rollback()

    @classmethod
    def load(cls, folder: str | Path, channels=None, voxel_size: float | None = None,
             roll_back: bool = False) -> "ReversibleMemory":
        """Reopen a folder; the deltas stay on disk there (read back when revised or removed).

        From the memory snapshot when ``deltas/snapshot.npz`` matches it, replaying the log's committed
        records after it; else the memory is rebuilt from the whole log (``channels`` and ``voxel_size``
        give its layout when there is no ``memory.npz``). The log's uncommitted tail is cut off. A map
        made before the log (one delta file a frame) loads as it was saved. ``roll_back``: a log whose
        shards end before a commit (a truncated file) is rolled back to the last commit they reach
        (:class:`~panovocc_cli.io.mapstore.DeltaLog`); else refused."""
        folder = Path(folder)
        mem_path = folder / mapstore.MEMORY_NAME
        has_log = bool(mapstore.shard_ids(folder))
        if mem_path.is_file():
            arrays, done, poses, ids = mapstore.read_memory(folder, sparse=True)
            committed = _pose_table(poses, done, ids)
            snap = _read_snapshot(folder, mem_path) if has_log or (folder / mapstore.DELTAS_DIR / SNAPSHOT_NAME).is_file() \
                else None
            if snap is None and not has_log:  # a map made before the log
                settle_staged(folder, committed)
                memory = VoxelMemory.from_arrays(arrays, mem_path)
                locs = {fid: (LEGACY, 0, 0) for fid in committed}
                log = mapstore.DeltaLog(folder, roll_back=roll_back)
                return cls(memory, DeltaStore(folder, _log=log, _locs=locs, _poses=committed))
            if snap is not None:
                locs = {int(i): tuple(int(v) for v in loc) for i, loc in zip(snap["frame_ids"], snap["locations"])}
                if set(locs) != set(committed):
                    raise PanovoccError("deltas/snapshot.npz does not list the frames memory.npz holds", mem_path)
                try:
                    log = mapstore.DeltaLog(folder, tuple(int(v) for v in snap["log_end"]), roll_back)
                except PanovoccError:  # the snapshot was written by a save that did not commit: rebuild
                    log = None
                if log is not None:
                    memory = VoxelMemory.from_arrays(arrays, mem_path)
                    rm = cls(memory, DeltaStore(folder, _log=log, _locs=locs, _poses=committed))
                    rm._replay(log.records)
                    if not log.records:
                        rm.loaded_snapshot = str(snap["memory_sha256"])
                    return rm
            channels = memory_specs(arrays) if channels is None else channels
            voxel_size = float(arrays["voxel_size"]) if voxel_size is None else voxel_size
        if channels is None or voxel_size is None:
            raise PanovoccError("memory.npz not found (not a panovocc map folder, or the run stopped before "
                                "its first checkpoint)", mem_path)
        # no usable snapshot: the memory is the sum of the committed records
        log = mapstore.DeltaLog(folder, roll_back=roll_back)
        rm = cls(VoxelMemory(voxel_size, channels), DeltaStore(folder, _log=log))
        rm._replay(log.records)
        return rm

    def _replay(self, records) -> None:
        """Apply committed log records (after the snapshot) to the memory and the store's index, in log order.
        The PUT records' payloads are read and decoded on a second thread, up to :data:`REPLAY_AHEAD` records
        ahead of the adds (a resumed run's replay of every record: the decoding and the add each about half of
        it); a record that cannot be read is refused when its turn comes, as in a plain loop."""
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        st = self.store
        records = list(records)

        def decoded(loc):
            return mapstore.decode_delta(st._log.read(loc), mapstore.shard_path(st.folder, loc[0]))

        puts = iter([loc for kind, _, loc in records if kind == mapstore.PUT])
        pool = ThreadPoolExecutor(max_workers=1)
        try:
            ahead = deque(pool.submit(decoded, loc) for _, loc in zip(range(REPLAY_AHEAD), puts))
            for kind, fid, loc in records:
                if fid in st.poses:
                    self.memory.add(st._read(fid, st._locs[fid]), -1)
                if kind == mapstore.PUT:
                    parts, T = ahead.popleft().result()
                    nxt = next(puts, None)
                    if nxt is not None:
                        ahead.append(pool.submit(decoded, nxt))
                    st.poses[fid], st._locs[fid] = T, loc
                    self.memory.add(FrameDelta(tuple(Delta(keys, ch) for keys, ch in parts)), +1)
                    del parts  # freed before the next record's wait, not beside it
                else:
                    st.poses.pop(fid, None)
                    st._locs.pop(fid, None)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # a refused record: those queued after it are not decoded

    def close(self) -> None:
        try:
            self._flush()
        finally:
            self.store.close()


def memory_specs(arrays) -> list:
    """The channel specs of a memory file's arrays."""
    from .memory import ChannelSpec

    return [ChannelSpec(str(n), int(w), str(k)) for n, w, k in
            zip(arrays["channel_names"], arrays["channel_widths"], arrays["channel_kinds"])]


def _pose_table(poses: np.ndarray, frames_done: int, ids: np.ndarray | None) -> dict:
    if ids is None:  # frames 0..frames_done-1 (a map run's checkpoint may list the poses of all its frames)
        ids = np.arange(min(frames_done, len(poses)))
        poses = poses[: len(ids)]
    return {int(i): np.asarray(T, np.float64) for i, T in zip(ids, poses)}


def settle_staged(folder: Path, committed: dict) -> None:
    """Maps made before the log: roll staged deltas forward when ``memory.npz`` already holds their pose,
    else delete them."""
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
