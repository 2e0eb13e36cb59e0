"""A writer's lock on an output folder (``OUT/.lock``): one writer at a time on a map.

``map``, ``map --resume``, ``map --overwrite`` and ``revise`` hold it for their whole run. A second writer
gets a :class:`PanovoccError` naming the holder (pid, host, command, start time).

The kernel arbitrates: the holder keeps ``OUT/.lock`` open with an exclusive ``fcntl.flock`` for the whole
run, so of any number of processes trying at once exactly one gets it, and a killed holder's lock is freed
by the kernel when the process dies. The file also records the holder's details (JSON), read only for the
refusal message. Whoever gets the flock then checks those details: a lock written by a live process on
this host that does not hold the flock (an older panovocc), or by a process on another host (whose flock
this host cannot see), is still refused; a lock left by a killed process is stale and taken over, on the
same host, when its pid is gone or now belongs to another process (the process start time, from
``/proc/PID/stat``, differs from the one recorded). Release removes the file while still holding the
flock; a process that opened the removed file notices (its inode is no longer ``OUT/.lock``) and tries
again.
"""

from __future__ import annotations

import errno
import fcntl
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


def take_flock(path: str | Path, create: bool = False, wait: bool = False) -> int | None:
    """Open ``path`` (a file, created when ``create``; or a folder) and take an exclusive ``fcntl.flock`` on it.

    Returns
    -------
    fd : int holding the lock until it is closed (or the process ends), or None when another open file
        holds it (only with ``wait=False``; with ``wait=True`` it waits for it)

    Raises
    ------
    FileNotFoundError when ``path`` is missing, or was removed or replaced while we waited for the lock
    (whoever removed it held the lock: what we locked is no longer ``path``).
    """
    fd = os.open(path, os.O_RDWR | os.O_CREAT if create else os.O_RDONLY, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            return None
        if not os.path.samestat(os.fstat(fd), os.stat(path)):
            raise FileNotFoundError(errno.ENOENT, "removed while being locked", str(path))
    except BaseException:
        try:
            os.close(fd)
        except OSError:
            pass
        raise
    return fd


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
        self._fd: int | None = None

    def _read(self) -> dict | None:
        try:
            d = json.loads(self.path.read_text(encoding="utf-8"))
            return d if isinstance(d, dict) else {}
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}  # unreadable: a lock nobody can name is stale

    def _holder(self) -> dict:
        """The details of the process holding the flock (it may be writing them right now: wait a little)."""
        held: dict | None = {}
        for _ in range(50):
            held = self._read()
            if held:
                return held
            time.sleep(0.01)
        return held or {}

    def _refuse(self, held: dict) -> PanovoccError:
        return PanovoccError(f"another writer holds this map folder: {_holder_text(held)}; wait for it to finish "
                             f"(or remove {self.path} if that process is gone)", self.folder)

    def acquire(self) -> "FolderLock":
        pid = os.getpid()
        info = {"pid": pid, "host": socket.gethostname(), "command": self.command, "started": time.time(),
                "proc_start": process_start_time(pid)}
        for _ in range(20):
            try:
                fd = take_flock(self.path, create=True)
            except FileNotFoundError:  # released (removed) between our open and our flock: try the new file
                continue
            if fd is None:
                raise self._refuse(self._holder())
            try:
                held = self._read()
                if held and not is_stale(held):  # a writer that holds no flock here (older panovocc, other host)
                    raise self._refuse(held)
                os.ftruncate(fd, 0)
                os.pwrite(fd, (json.dumps(info) + "\n").encode("utf-8"), 0)
                self._fd, fd, self.info = fd, None, info
                return self
            finally:
                if fd is not None:
                    os.close(fd)  # frees the flock
        raise PanovoccError("could not take the folder lock (it keeps changing hands)", self.folder)

    def release(self) -> None:
        """Remove the lock file, then drop the flock (the kernel drops it anyway when the process ends)."""
        if self._fd is None:
            return
        try:
            if os.path.samestat(os.fstat(self._fd), os.stat(self.path)):  # still ours (not removed by hand)
                self.path.unlink()
        except FileNotFoundError:
            pass
        finally:
            os.close(self._fd)
            self._fd, self.info = None, None

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
