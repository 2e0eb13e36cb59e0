"""Run a task graph: on Dask distributed (a local cluster, or an existing one by address) or in process.

Finished tasks are read from the cache and never submitted; the others go to the scheduler with their
inputs as dependencies (``client.submit(execute, ...)``), each under a key derived from its hash. A
worker that dies mid-task loses nothing that finished: the scheduler runs the lost task again on
another worker, and any finished input it needs again is found in the cache (``status: cached``), not
recomputed. The cache folder must be visible to every worker at the same path (a local cluster: always;
a remote one: a shared file system).

Progress: a bar over the tasks (computed / cached / failed so far), and one line per failure.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable

from ..errors import PanovoccError
from .tasks import Task, clean_stale, execute, read_done

# Threads per worker process for the kernels (numba, OpenMP): one, so two workers fill two cores.
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1"}


def run_tasks(tasks: Iterable[Task], cache: str | Path, scheduler: str | None = None, workers: int = 2,
              progress: bool = True, log=sys.stderr, client=None) -> dict[str, dict]:
    """Make every task's output exist in ``cache``; returns key -> result (``task.json`` plus ``status``:
    ``cached`` | ``computed`` | ``failed`` with ``error``).

    Parameters
    ----------
    tasks : in dependency order (:func:`~.tasks.topological`)
    cache : the cache folder (created)
    scheduler : a Dask scheduler address (``tcp://host:8786``) to use an existing cluster; None: a new
        ``LocalCluster`` of ``workers`` processes with one thread each; ``workers == 0`` (and no address):
        run in this process, one task after the other
    client : an existing ``distributed.Client`` (tests); takes precedence over ``scheduler``
    """
    tasks = list(tasks)
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    stale = clean_stale(cache)
    if stale and progress:
        print(f"removed {stale} unfinished task folder(s) of an interrupted sweep", file=log)
    results: dict[str, dict] = {}
    todo = []
    for t in tasks:
        done = read_done(cache, t.kind, t.key)
        if done is not None:
            results[t.key] = {**done, "status": "cached", "seconds": 0.0}
        else:
            todo.append(t)
    bar = _Bar(len(tasks), len(tasks) - len(todo), progress, log)
    try:
        if not todo:
            return results
        if client is None and scheduler is None and workers == 0:
            _run_in_process(todo, cache, results, bar)
        else:
            _run_dask(todo, cache, results, bar, scheduler, workers, client, log)
    finally:
        bar.close()
    return results


def _run_in_process(todo: list[Task], cache: Path, results: dict, bar: "_Bar") -> None:
    for t in todo:
        if any(results.get(d.key, {}).get("status") == "failed" for d in t.deps):
            results[t.key] = _failed(t, "an input failed")
        else:
            try:
                results[t.key] = execute(t.to_dict(), str(cache))
            except Exception as e:  # noqa: BLE001 - one broken task must not stop the sweep: reported
                results[t.key] = _failed(t, str(e) if isinstance(e, PanovoccError) else f"{type(e).__name__}: {e}")
        bar.update(t, results[t.key])


@contextmanager
def dask_client(scheduler: str | None = None, workers: int = 2, client=None, log=None, timeout: str = "30s",
                env: dict | None = None):
    """A ``distributed.Client``: ``client`` itself when given; else one connected to the scheduler at
    ``scheduler`` (one line, :class:`PanovoccError`, when it cannot be reached within ``timeout``); else a
    new ``LocalCluster`` of ``workers`` processes with one thread each (:data:`WORKER_ENV`, plus ``env``),
    closed on exit. ``log``: a stream for one line naming the workers and the dashboard."""
    from contextlib import ExitStack

    from distributed import Client, LocalCluster

    with ExitStack() as stack:
        if client is None:
            if scheduler:
                try:
                    client = stack.enter_context(Client(scheduler, timeout=timeout))
                except (OSError, TimeoutError) as e:
                    raise PanovoccError(f"cannot reach the Dask scheduler at {scheduler} ({e})") from None
            else:
                cluster = stack.enter_context(LocalCluster(
                    n_workers=max(1, workers), threads_per_worker=1, processes=True, dashboard_address=":0",
                    env={**WORKER_ENV, **(env or {})}, silence_logs=40))
                client = stack.enter_context(Client(cluster))
        if log is not None:
            n = len(client.scheduler_info().get("workers", {}))
            link = getattr(client, "dashboard_link", None)
            print(f"dask: {n} worker(s) at {client.scheduler.address}" + (f", dashboard {link}" if link else ""),
                  file=log, flush=True)
        yield client


def _run_dask(todo, cache: Path, results: dict, bar: "_Bar", scheduler, workers: int, client, log) -> None:
    from distributed import as_completed

    with dask_client(scheduler, workers, client, log if bar.enabled else None) as client:
        futures: dict[str, Any] = {}
        by_future = {}
        for t in todo:
            deps = [futures[d.key] for d in t.deps if d.key in futures]
            f = client.submit(execute, t.to_dict(), str(cache), *deps, key=t.dask_key, pure=False)
            futures[t.key] = f
            by_future[f.key] = t
        for f in as_completed(list(futures.values())):
            t = by_future[f.key]
            if f.status == "finished":
                results[t.key] = f.result()
            else:
                try:
                    err = f.exception()
                except Exception as e:  # noqa: BLE001 - a cancelled or lost future: report it, go on
                    err = e
                results[t.key] = _failed(t, f"{type(err).__name__}: {err}" if not isinstance(err, PanovoccError)
                                         else str(err))
            bar.update(t, results[t.key])


def _failed(t: Task, error: str) -> dict:
    return {"key": t.key, "kind": t.kind, "label": t.label, "status": "failed", "error": error}


class _Bar:
    """Progress over the tasks: a tqdm bar with counts, one line per failure."""

    def __init__(self, total: int, cached: int, enabled: bool, log):
        self.enabled, self.log = enabled, log
        self.n = {"computed": 0, "cached": cached, "failed": 0}
        self.seconds: dict[str, float] = {}  # compute seconds per task kind (the summary line)
        self.t0 = time.perf_counter()
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=cached, desc="tasks", unit="task", file=log, dynamic_ncols=True)
            self.bar.set_postfix(self.n)

    def update(self, t: Task, res: dict) -> None:
        st = res["status"]
        self.n[st] = self.n.get(st, 0) + 1
        if st == "computed":
            self.seconds[t.kind] = self.seconds.get(t.kind, 0.0) + float(res.get("seconds", 0.0))
        if self.bar is not None:
            if st == "failed":
                self.bar.write(f"failed: {t.label}: {res['error']}", file=self.log)
            self.bar.set_postfix(self.n, refresh=False)
            self.bar.set_description(f"{t.kind} {t.label.split(' ', 1)[-1]}"[:48], refresh=False)
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            print(f"tasks: {self.n['computed']} computed, {self.n['cached']} cached, {self.n['failed']} failed "
                  f"in {time.perf_counter() - self.t0:.1f} s", file=self.log, flush=True)
            if self.seconds:
                print("task seconds by kind (summed over workers): " + ", ".join(
                    f"{k} {v:.0f}" for k, v in sorted(self.seconds.items(), key=lambda kv: -kv[1])), file=self.log,
                    flush=True)
