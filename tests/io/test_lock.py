"""The folder lock (io/lock.py): the kernel arbitrates who holds it, so a stale lock cleared by many
processes at once ends with exactly one holder."""

from __future__ import annotations

import json
import multiprocessing as mp
import random
import socket
import subprocess
import sys
import time

import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.lock import FolderLock


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _stale(folder) -> None:
    (folder / ".lock").write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname(), "command": "x",
                                              "started": time.time() - 60, "proc_start": 1}))


def _racer(folder, start, done, results, seed) -> None:
    rng = random.Random(seed)
    real_read = FolderLock._read

    def slow_read(self):  # a process descheduled between reading the lock and acting on what it read
        d = real_read(self)
        time.sleep(rng.uniform(0, 0.03))
        return d

    FolderLock._read = slow_read
    start.wait()
    lock = FolderLock(folder, "racer")
    try:
        lock.acquire()
    except PanovoccError:
        results.put(0)
        done.wait()
        return
    results.put(1)
    done.wait()  # hold it until every racer has tried
    lock.release()


@pytest.mark.parametrize("round_", range(3))
def test_many_processes_racing_for_a_stale_lock_one_wins(tmp_path, round_):
    ctx = mp.get_context("fork")
    n = 12
    _stale(tmp_path)
    start, done, results = ctx.Barrier(n), ctx.Barrier(n + 1), ctx.Queue()
    procs = [ctx.Process(target=_racer, args=(tmp_path, start, done, results, 100 * round_ + k)) for k in range(n)]
    for p in procs:
        p.start()
    won = [results.get(timeout=60) for _ in range(n)]
    holder = json.loads((tmp_path / ".lock").read_text())
    done.wait(timeout=60)
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    assert sum(won) == 1
    assert holder["command"] == "racer"
    assert not (tmp_path / ".lock").exists()  # released by its holder


def test_second_holder_is_refused_naming_the_first_and_released_lock_is_free(tmp_path):
    with FolderLock(tmp_path, "first cmd"):
        with pytest.raises(PanovoccError, match="first cmd") as e:
            FolderLock(tmp_path, "second").acquire()
        assert "\n" not in str(e.value)
    assert not (tmp_path / ".lock").exists()
    with FolderLock(tmp_path, "third"):
        assert json.loads((tmp_path / ".lock").read_text())["command"] == "third"


def test_a_killed_holder_leaves_a_lock_the_next_writer_takes(tmp_path):
    code = (f"import os, sys; from panovocc_cli.io.lock import FolderLock; FolderLock({str(tmp_path)!r}, 'killed')"
            ".acquire(); print('held', flush=True); sys.stdin.read()")
    p = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "held"
        with pytest.raises(PanovoccError, match="killed"):
            FolderLock(tmp_path, "second").acquire()
    finally:
        p.kill()
        p.wait()
    assert json.loads((tmp_path / ".lock").read_text())["command"] == "killed"
    with FolderLock(tmp_path, "next"):
        assert json.loads((tmp_path / ".lock").read_text())["command"] == "next"
