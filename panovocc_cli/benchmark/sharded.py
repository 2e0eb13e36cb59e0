"""``panovocc map --workers N | --scheduler ADDRESS``: a sequence's frames integrated in shards on Dask workers.

The client (:func:`panovocc_cli.mapping.pipeline.run_map` with ``shards=DaskShards(client)``) cuts the
frames into contiguous shards (:func:`~panovocc_cli.mapping.shards.shard_ranges`, a few per worker) and
submits one task a shard. A worker reads and segments its frames (its frame source is built once per
process and kept: the sequence, the segmenter, numba's kernels stay warm between shards), computes each
frame's delta, and returns

* the shard's delta records: each frame's PUT payload, the very bytes the sequential run appends to its
  delta log (Zstandard-compressed sparse deltas, about 0.5 MB a frame at 512x256 with 12 classes), sent to the
  client, which appends them in frame order to ``OUT/deltas/`` (so ``revise`` and ``--resume`` read the
  folder as they read a sequential run's, and checkpoints are made as the sequential run makes them);
* the shard's partial memory (:func:`~panovocc_cli.mapping.shards.encode_partial`: its non-zero voxels in
  the same compact encoding), which stays on the cluster: pairs of partial memories are added by further
  tasks, a tree whose top (its last two sums) goes to the client, which adds each to its memory as soon as
  it is done.

Integer sums are exact and order-free, so the folder's bytes do not depend on the number of workers, on
the shards, or on failures: a worker lost mid-shard (its process dies) has that shard, and any partial sum
it held, computed again by the scheduler on another worker. Workers must run the client's code (the
benchmark runner's fingerprint, :func:`~.tasks.check_code`) and see the sequence at the same path.
"""

from __future__ import annotations

import functools
import json
import os
import time
import uuid

from ..errors import PanovoccError
from ..mapping.config import MapConfig
from ..mapping.shards import decode_partial, integrate_shard, shard_ranges, sum_partials, warm_kernels
from .tasks import check_code, code_fingerprint

WAIT_FOR_WORKERS_S = 60  # a scheduler without workers: how long to wait for the first one
SHARDS_PER_WORKER = 1  # shards a worker gets: each costs a partial memory (made, encoded, summed), ~0.7 s on a
#                       home at 512x256 (docs/sharding.md, "Throughput"); more balance a slow worker better
TOP_PARTIALS = 2  # the partial sums the client adds itself (the tree stops there)
EXIT_HOOK_ENV = "PANOVOCC_TEST_SHARD_EXIT"  # tests: a marker path; the first worker to reach the middle of a
#                                             shard creates it and exits at once (a worker lost mid-shard)


@functools.lru_cache(maxsize=2)
def _frames(cfg_json: str):
    """This worker process's frame source of a run (built once: sequence, poses, segmenter)."""
    from ..mapping.pipeline import open_frames

    return open_frames(MapConfig.from_json(json.loads(cfg_json), "the client's map config"))


def _exit_hook(ids):
    mark = os.environ.get(EXIT_HOOK_ENV)
    if not mark or len(ids) < 2:
        return None

    def after(k):
        if k == len(ids) // 2 - 1:
            try:
                os.close(os.open(mark, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            except FileExistsError:
                return
            os._exit(1)
    return after


def _prepare(cfg_json: str, code: str, what: str):
    from ..runtime import setup

    setup()
    check_code(code, what, "the client")
    return _frames(cfg_json)


def _progress_hook(topic: str | None, exit_hook):
    """After each frame of a shard: the exit hook (tests), then one event on ``topic`` (the client's
    progress bar counts frames as the workers integrate them, not only as whole shards come back)."""
    if not topic:
        return exit_hook
    from distributed import get_worker

    try:
        worker = get_worker()
    except ValueError:  # not on a Dask worker (called directly): no events
        return exit_hook

    def after(k):
        if exit_hook is not None:
            exit_hook(k)
        worker.log_event(topic, 1)
    return after


def shard_task(cfg_json: str, code: str, ids: list, topic: str | None = None) -> tuple:
    """On a worker: integrate frames ``ids``; returns (records, partial memory bytes, their length, the
    worker's CPU seconds on them). ``topic``: an event is logged on it after each frame."""
    frames = _prepare(cfg_json, code, f"the shard of frames {ids[0]}:{ids[-1] + 1}")
    cfg = MapConfig.from_json(json.loads(cfg_json), "the client's map config")
    c0 = time.process_time()
    records, partial = integrate_shard(cfg.mapper_config(), frames, ids, _progress_hook(topic, _exit_hook(ids)))
    return records, partial, len(partial), time.process_time() - c0


def warm_task(cfg_json: str, code: str, frame_id: int) -> int:
    """On a worker: check its code, open the run's frame source and integrate one frame (numba's kernels
    loaded, the segmenter built) without keeping anything; returns the worker's process id."""
    frames = _prepare(cfg_json, code, "a worker")
    cfg = MapConfig.from_json(json.loads(cfg_json), "the client's map config")
    integrate_shard(cfg.mapper_config(), frames, [frame_id])
    return os.getpid()


def code_task(code: str) -> int:
    """On a worker: refuse when it runs other code than the client's (:func:`~.tasks.check_code`); its pid."""
    check_code(code, "a worker", "the client")
    return os.getpid()


def _records(result: tuple) -> tuple:
    return result[0], result[2], result[3]


def _partial(result: tuple) -> bytes:
    return result[1]


class DaskShards:
    """The ``shards`` of :func:`~panovocc_cli.mapping.pipeline.run_map` on a Dask client.

    Parameters
    ----------
    client : distributed.Client
    shards_per_worker : shards per worker (the frames are cut into ``workers x shards_per_worker`` runs)
    warm : first integrate one frame on every worker (each checks its code) and load the client's memory
        kernels (timing runs start warm)

    After a run, :attr:`stats` holds the shard count, workers, the bytes sent back: records (to the
    client) and partial memories (to the tree's sums; its top two to the client: ``root_bytes``), the wall seconds of the run
    after the warm-up, the workers' CPU seconds in the shards and the client's CPU seconds meanwhile.
    """

    def __init__(self, client, shards_per_worker: int = SHARDS_PER_WORKER, warm: bool = True):
        self.client = client
        self.shards_per_worker = int(shards_per_worker)
        self.warm = warm
        self.stats: dict = {}
        self.progress = None  # a tqdm bar, set by run_map: advanced as the workers integrate frames

    def _submit(self, fn, *args, key: str):
        return self.client.submit(fn, *args, key=key, pure=False)

    def _result(self, future):
        try:
            return future.result()
        except PanovoccError:
            raise
        except Exception as e:  # noqa: BLE001 - a worker's failure other than bad input: one line
            raise PanovoccError(f"a shard failed on the Dask cluster ({type(e).__name__}: {e})") from None

    def check_workers(self) -> None:
        """Before anything is written: every worker runs the client's code (one line naming the first that
        does not), and there is at least one (waiting :data:`WAIT_FOR_WORKERS_S` for it)."""
        if not self.client.scheduler_info().get("workers"):
            try:
                self.client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_S)
            except TimeoutError:
                raise PanovoccError(f"the Dask scheduler at {self.client.scheduler.address} has no workers (none "
                                    f"joined within {WAIT_FOR_WORKERS_S} s): start some (docs/sharding.md)") from None
        code, token = code_fingerprint(), uuid.uuid4().hex[:12]
        workers = list(self.client.scheduler_info().get("workers", {}))
        futs = [self.client.submit(code_task, code, key=f"panovocc-code-{token}-{k}", workers=[w],
                                   allow_other_workers=True, pure=False) for k, w in enumerate(workers)]
        for f in futs:
            self._result(f)

    def warm_workers(self, cfg: MapConfig, frame_id: int) -> list:
        """Integrate frame ``frame_id`` once on every worker (discarded): the code checked, kernels loaded."""
        cfg_json, code = json.dumps(cfg.to_json(), sort_keys=True), code_fingerprint()
        token = uuid.uuid4().hex[:12]
        workers = list(self.client.scheduler_info().get("workers", {}))
        futs = [self.client.submit(warm_task, cfg_json, code, int(frame_id), key=f"panovocc-warm-{token}-{k}",
                                   workers=[w], allow_other_workers=True, pure=False) for k, w in enumerate(workers)]
        return [self._result(f) for f in futs]

    def __call__(self, mapper, cfg: MapConfig, ids):
        ids = [int(i) for i in ids]
        if not ids:
            return
        if not self.client.scheduler_info().get("workers"):
            self.check_workers()
        workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        if self.warm:
            self.warm_workers(cfg, ids[0])
            warm_kernels(cfg.mapper_config())  # the client's adds of the top sums: kernels loaded before the clock
        t0, c0 = time.perf_counter(), time.process_time()
        cfg_json, code = json.dumps(cfg.to_json(), sort_keys=True), code_fingerprint()
        ranges = shard_ranges(ids, workers * self.shards_per_worker)
        token = uuid.uuid4().hex[:12]
        topic = f"panovocc-progress-{token}" if self.progress is not None else None
        advance = _Advance(self.progress, len(ids))
        if topic is not None:
            self.client.subscribe_topic(topic, lambda event: advance(int(event[1])))
        try:
            yield from self._run(mapper, ids, ranges, workers, cfg_json, code, token, topic)
        finally:
            if topic is not None:
                self.client.unsubscribe_topic(topic)
        advance(len(ids))  # events are best effort: the bar ends full once every record is kept
        self.stats.update(seconds=time.perf_counter() - t0, client_cpu_s=time.process_time() - c0)

    def _run(self, mapper, ids, ranges, workers, cfg_json, code, token, topic):
        from distributed import as_completed

        shards = [self._submit(shard_task, cfg_json, code, r, topic, key=f"panovocc-shard-{token}-{k:05d}")
                  for k, r in enumerate(ranges)]
        records = [self._submit(_records, f, key=f"panovocc-records-{token}-{k:05d}") for k, f in enumerate(shards)]
        level = [self._submit(_partial, f, key=f"panovocc-partial-{token}-{k:05d}") for k, f in enumerate(shards)]
        del shards  # each shard's result is freed once its records and partial memory are taken from it
        depth = 0
        while len(level) > TOP_PARTIALS:  # the tree reduction: neighbours added pairwise, on the cluster
            depth += 1
            level = [self._submit(sum_partials, *level[j:j + 2], key=f"panovocc-sum-{token}-{depth}-{j:05d}")
                     if j + 1 < len(level) else level[j] for j in range(0, len(level), 2)]
        # the tree's top (one or two partial sums) is added here, each as soon as it is done, while later
        # shards still run: no last sum task, no encoding of its result (integer sums: any order, exact)
        index = {f.key: k for k, f in enumerate(records)}
        top = {f.key for f in level}
        arrived, nxt = {}, 0
        record_bytes = partial_bytes = root_bytes = 0
        shard_cpu = 0.0
        for fut in as_completed([*records, *level]):
            if fut.key in top:
                blob = self._result(fut)
                fut.release()
                root_bytes += len(blob)
                h, specs, delta = decode_partial(blob)
                del blob
                if h != mapper.memory.voxel_size or list(specs) != list(mapper.memory.specs):
                    raise PanovoccError("the workers' partial memory has another channel layout than the map")
                mapper.add_sum(delta)
                del delta
                continue
            k = index[fut.key]
            arrived[k] = self._result(fut)
            fut.release()
            while nxt in arrived:
                rec, nbytes, cpu = arrived.pop(nxt)
                record_bytes += rec.nbytes()
                partial_bytes += nbytes
                shard_cpu += cpu
                empty = set(rec.empty)
                for fid, T, payload in zip(rec.ids, rec.poses, rec.payloads):
                    mapper.keep_encoded(fid, payload, T, empty=fid in empty)
                    yield fid
                nxt += 1
        self.stats = {"shard_cpu_s": shard_cpu, "shards": len(ranges), "workers": workers, "frames": len(ids), "record_bytes": record_bytes,
                      "partial_bytes": partial_bytes, "root_bytes": root_bytes}


class _Advance:
    """``advance(k)``: move ``bar`` on by ``k`` frames, never past ``total`` (a shard computed again after a
    lost worker reports its frames twice). Called from the client's event loop and from its own thread."""

    def __init__(self, bar, total: int):
        import threading

        self.bar, self.total, self.done = bar, int(total), 0
        self._lock = threading.Lock()

    def __call__(self, k: int) -> None:
        if self.bar is None:
            return
        with self._lock:
            k = max(0, min(int(k), self.total - self.done))
            self.done += k
        if k:
            self.bar.update(k)
