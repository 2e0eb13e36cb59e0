"""Write to a temporary name beside the target, then rename: nothing half-written is ever left."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _publish_mode(path: Path, base: int) -> None:
    """Give a temporary file/folder the mode a plain ``open``/``mkdir`` would (mkstemp makes it 0600)."""
    os.chmod(path, base & ~_umask())


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary file path in the target's folder; rename it onto ``path`` on success.

    The temporary name keeps the target's suffix (libraries choose formats by it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _publish_mode(tmp_path, 0o666)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` whole."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        yield tmp
        _publish_mode(tmp, 0o777)
        if path.exists():
            if not overwrite:
                raise FileExistsError(path)
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old / "x")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def check_output_path(path: str | Path, folder: bool = False) -> None:
    """Refuse an output path that cannot be written: an existing ancestor that is a file, or the wrong kind.

    Parameters
    ----------
    path : the output file or folder
    folder : True when a folder is expected (an existing file there is refused), False for a file (an
        existing folder there is refused)

    Raises
    ------
    PanovoccError naming the offending path (exit status 2).
    """
    from ..errors import PanovoccError

    path = Path(path)
    for parent in Path(os.path.abspath(os.fspath(path))).parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise PanovoccError("cannot write here: a parent of the output is a file, not a folder", parent)
            break
    if folder and (path.exists() or path.is_symlink()) and not path.is_dir():
        raise PanovoccError("exists and is not a folder (expected an output folder)", path)
    if not folder and path.is_dir():
        raise PanovoccError("is a folder; expected an output file path", path)


@contextlib.contextmanager
def output_folder(path: str | Path) -> Iterator[Path]:
    """Create the output folder ``path`` (and missing parents) for the block; remove what it created on failure.

    A folder that existed before is kept as it was around the block (files the block wrote atomically
    into it stay); a folder this call created is removed whole if the block raises, so a failed command
    leaves no empty folder behind.
    """
    path = Path(path)
    check_output_path(path, folder=True)
    created = None
    for p in [path, *path.parents]:
        if p.exists() or p.is_symlink():
            break
        created = p
    try:
        path.mkdir(parents=True, exist_ok=True)
        yield path
    except BaseException as e:
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)
        if isinstance(e, OSError):  # disk full, read-only file system, permissions
            raise _write_error(e, path) from None
        raise


@contextlib.contextmanager
def output_file(path: str | Path) -> Iterator[Path]:
    """Check an output file path (:func:`check_output_path`) and turn an ``OSError`` raised while writing it
    (disk full, read-only file system) into one :class:`PanovoccError` line. Write atomically inside."""
    path = Path(path)
    check_output_path(path, folder=False)
    try:
        yield path
    except OSError as e:
        raise _write_error(e, path) from None


def _write_error(e: OSError, path: Path):
    from ..errors import PanovoccError

    where = e.filename if getattr(e, "filename", None) else path
    return PanovoccError(f"cannot write ({e.strerror or type(e).__name__})", where)


def write_text(path: str | Path, text: str) -> None:
    """Atomically write a text file (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
