"""The sweep on a local Dask cluster of two workers, one of them killed mid-task: the sweep completes,
every task is computed exactly once (finished inputs come from the cache, not recomputed), and the
tables are byte-identical to the in-process run's."""

import os
import signal
import threading
import time

from panovocc_cli.benchmark.runner import WORKER_ENV
from panovocc_cli.benchmark.tasks import computed_events

from bench_helpers import reproduce, tree_bytes


def _kill_first_map_worker(client, cache, pids, done: dict, stop: threading.Event):
    """Wait until a map task is running (its temporary folder exists), then SIGKILL the worker running it."""
    while not stop.is_set():
        tmp = list((cache / "map").glob(".*.tmp.*")) if (cache / "map").is_dir() else []
        if tmp:
            short = tmp[0].name[1:17]
            for addr, keys in client.processing().items():
                if any(k == f"map-{short}" for k in keys) and addr in pids:
                    finished = (cache / "map" / short / "task.json").exists()
                    os.kill(pids[addr], signal.SIGKILL)
                    done.update(worker=addr, task=short, finished_before_kill=finished)
                    return
        time.sleep(0.02)


def test_sweep_survives_a_killed_worker(tiny_sweep, tmp_path):
    from distributed import Client, LocalCluster

    ref_out, _, ref = tiny_sweep
    out, cache = tmp_path / "results", tmp_path / "cache"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0", env=WORKER_ENV,
                      silence_logs=50) as cluster, Client(cluster) as client:
        pids = client.run(os.getpid)
        assert len(pids) == 2
        killed: dict = {}
        stop = threading.Event()
        watcher = threading.Thread(target=_kill_first_map_worker, args=(client, cache, pids, killed, stop), daemon=True)
        watcher.start()
        try:  # the sweep connects to the running cluster by address (--scheduler), as a user's would
            s = reproduce(out, cache, scheduler=cluster.scheduler_address)
        finally:
            stop.set()
            watcher.join(10)
    assert killed and not killed["finished_before_kill"], killed  # a worker died in the middle of a map task
    assert s["failed"] == [] and s["tasks"] == ref["tasks"]
    events = computed_events(cache)
    assert len(events) == s["tasks"] and set(events.values()) == {1}, events  # nothing computed twice
    assert (cache / "map" / killed["task"] / "task.json").is_file()  # the killed task was run again, elsewhere
    # byte-identical tables to the in-process reference run (other executor, other cache, one thread a worker)
    assert tree_bytes(out) == tree_bytes(ref_out)
