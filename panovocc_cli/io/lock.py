"""A writer's lock on an output folder (``OUT/.lock``): one writer at a time on a map.

``map``, ``map --resume``, ``map --overwrite`` and ``revise`` hold it for their whole run. A second writer
gets a :class:`PanovoccError` naming the holder (pid, host, command, start time). A lock left by a killed
process is stale and is cleared: on the same host, when its pid is gone or now belongs to another process
(the process start time, from ``/proc/PID/stat``, differs from the one recorded).

The lock file is written whole under a temporary name and hard-linked into place (``os.link`` fails when
the name exists), so a reader never sees a half-written lock and two writers never both win.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from pathlib import Path

from ..errors import PanovoccError

LOCK_NAME = ".lock"


def process_start_time(pid: int) -> int | None:
    """Start time of process ``pid`` in clock ticks since boot (``/proc/PID/stat`` field 22), or None when
    there is no such process (or no /proc)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (OSError, ValueError):
        return None
    try:  # the command name (field 2) is in parentheses and may hold spaces
        return int(stat[stat.rindex(")") + 2:].split()[19])
    except (ValueError, IndexError):
        return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _holder_text(info: dict) -> str:
    started = info.get("started")
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(started)) if isinstance(started, (int, float)) else "?"
    return (f"pid {info.get('pid', '?')} on host {info.get('host', '?')} (command: {info.get('command', '?')}, "
            f"started {when})")


def is_stale(info: dict) -> bool:
    """Whether the process that wrote lock ``info`` is gone (same host only; another host's lock is kept)."""
    if info.get("host") != socket.gethostname():
        return False
    try:
        pid = int(info["pid"])
    except (KeyError, TypeError, ValueError):
        return True
    if not _pid_alive(pid):
        return True
    now = process_start_time(pid)
    rec = info.get("proc_start")
    return now is not None and rec is not None and int(rec) != now  # the pid was reused


class FolderLock:
    """Context manager holding ``folder/.lock``; ``command`` is recorded for whoever is refused.

    Raises
    ------
    PanovoccError when another live writer holds the folder (exit 2, one line naming it).
    """

    def __init__(self, folder: str | Path, command: str | None = None):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.command = command or " ".join(["panovocc", *sys.argv[1:]])[:200]
        self.info: dict | None = None

    def _read(self) -> dict | None:
        try:
            d = json.loads(self.path.read_text(encoding="utf-8"))
            return d if isinstance(d, dict) else {}
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}  # unreadable: a lock nobody can name is stale

    def acquire(self) -> "FolderLock":
        pid = os.getpid()
        self.info = {"pid": pid, "host": socket.gethostname(), "command": self.command, "started": time.time(),
                     "proc_start": process_start_time(pid)}
        tmp = self.folder / f".lock.{pid}.{time.monotonic_ns()}"
        tmp.write_text(json.dumps(self.info) + "\n", encoding="utf-8")
        try:
            for _ in range(5):
                try:
                    os.link(tmp, self.path)
                    return self
                except FileExistsError:
                    pass
                held = self._read()
                if held is None:
                    continue  # released meanwhile: try again
                if held and not is_stale(held):
                    raise PanovoccError(f"another writer holds this map folder: {_holder_text(held)}; wait for it "
                                        f"to finish (or remove {self.path} if that process is gone)", self.folder)
                self._clear_stale(held)
            raise PanovoccError("could not take the folder lock (it keeps changing hands)", self.folder)
        finally:
            tmp.unlink(missing_ok=True)

    def _clear_stale(self, held: dict) -> None:
        """Remove a stale lock, unless another writer replaced it meanwhile (then the next try sees that one)."""
        again = self._read()
        if again == held:
            self.path.unlink(missing_ok=True)

    def release(self) -> None:
        if self.info is not None and self._read() == self.info:
            self.path.unlink(missing_ok=True)
        self.info = None

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
