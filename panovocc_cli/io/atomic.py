"""Write to a temporary name beside the target, then rename: nothing half-written is ever left."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from ..errors import PanovoccError


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
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix if suffix is not None else path.suffix,
                                   dir=path.parent)
    except OSError as e:
        raise PanovoccError(f"cannot write ({e.strerror or e})", path) from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _publish_mode(tmp_path, 0o666)
        os.replace(tmp_path, path)
    except OSError as e:  # disk full, read-only file system, permissions: one line naming the target
        raise PanovoccError(f"cannot write ({e.strerror or e}); nothing was changed", path) from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path, overwrite: bool = True) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` whole."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    except OSError as e:
        raise PanovoccError(f"cannot write ({e.strerror or e})", path) from None
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
    except OSError as e:
        raise PanovoccError(f"cannot write ({e.strerror or e}); nothing was changed", path) from None
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


def _first_missing(path: Path) -> Path | None:
    """The outermost of ``path`` and its ancestors that does not exist (what ``mkdir(parents=True)`` makes)."""
    created = None
    for p in [path, *path.parents]:
        if p.exists() or p.is_symlink():
            break
        created = p
    return created


def check_writable_folder(path: str | Path) -> None:
    """Refuse, before any work, an output folder that cannot be written (a read-only file system, ``/proc``,
    no permission): the folder (and missing parents) is made and a file created in it, then what this made
    is removed again.

    Raises
    ------
    PanovoccError naming the folder: ``cannot write (REASON)``.
    """
    import tempfile

    path = Path(path)
    check_output_path(path, folder=True)
    created = _first_missing(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=".panovocc-probe.", dir=path)
        os.close(fd)
        os.unlink(name)
    except OSError as e:
        raise _write_error(e, path) from None
    finally:
        if created is not None:
            shutil.rmtree(created, ignore_errors=True)


@contextlib.contextmanager
def output_folder(path: str | Path) -> Iterator[Path]:
    """Create the output folder ``path`` (and missing parents) for the block; remove what it created on failure.

    A folder that existed before is kept as it was around the block (files the block wrote atomically
    into it stay); a folder this call created is removed whole if the block raises, so a failed command
    leaves no empty folder behind.
    """
    path = Path(path)
    check_output_path(path, folder=True)
    created = _first_missing(path)
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


# ---------------------------------------------------------------------------------------------
# Output guard: no command deletes or overwrites what it did not create.

#: A folder is a panovocc output of a kind when it holds one of these files (relative paths).
OUTPUT_MARKERS: dict[str, tuple[str, ...]] = {
    "scene": ("habitat/info_semantic.json", "habitat/mesh_semantic.ply"),
    "sequence": ("meta.json",),
    "map": ("config.json",),
    "eval": ("scores.json", "scores.csv", "counts.csv"),
    "coverage": ("coverage.csv",),
    "views": ("views.json",),
    "baseline": ("baseline.json",),
    "demo": ("scene/habitat/info_semantic.json", "seq/meta.json", "gt.npz", "map/config.json"),
}

#: Hidden files a panovocc writer may leave in a folder it owns (a lock, atomic-write temporaries).
IGNORED_IN_EMPTY = (".lock",)


#: Output folders whose files other commands read as data (a map's memory.npz, a sequence's frames): a file
#: output never replaces one of their files, even with --overwrite (a new file beside them is fine).
DATA_KINDS = ("scene", "sequence", "map", "views", "baseline")


def _resolved(p: str | Path) -> Path:
    """``p`` absolute with every symbolic link resolved (for a path that does not exist yet, its existing part):
    an output reached through a link is compared with the inputs where it really lies."""
    return Path(os.path.realpath(os.fspath(p)))


def _same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two existing paths are one file (hard links, bind mounts); False when either is missing."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def _data_owner(path: Path) -> tuple[str, Path] | None:
    """The nearest folder above ``path`` (resolved) that is a panovocc output of a :data:`DATA_KINDS` kind."""
    for folder in _resolved(path).parents:
        for kind in DATA_KINDS:
            if is_output_of_kind(folder, kind):
                return kind, folder
    return None


def _is_within(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _is_map_config(path: Path) -> bool:
    """A map's ``config.json`` (it has a ``geometry`` section); every stage writes a ``config.json`` beside its
    outputs (io/runconfig.py), so the file name alone does not make a folder a map."""
    import json

    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and "geometry" in d


def is_output_of_kind(path: str | Path, kind: str) -> bool:
    """Whether the folder ``path`` holds a marker file of a panovocc output of ``kind`` (see OUTPUT_MARKERS)."""
    path = Path(path)
    if kind == "map":
        return _is_map_config(path / "config.json")
    return any((path / m).is_file() for m in OUTPUT_MARKERS[kind])


def check_output(path: str | Path, kind: str, overwrite: bool = False, inputs=(), folder: bool = True) -> None:
    """Refuse an output that would delete or overwrite what the command did not create.

    Rules (README, "Behaviour you can rely on"):

    - an output never is an input, never lies inside a folder input and, as a folder, never holds an input
      (replacing it would delete the input), with or without ``--overwrite``; paths are compared with their
      symbolic links resolved, and an existing output that is the same file as an input (a hard link) is refused;
    - a file output never replaces a file of a panovocc output folder that other commands read
      (:data:`DATA_KINDS`: a scene, a sequence, a map, views, a baseline), even with ``--overwrite``;
    - a folder output may be missing or an empty folder; an existing non-empty folder is refused unless
      ``overwrite``, and even then only a panovocc output of the same ``kind`` (its marker file, see
      :data:`OUTPUT_MARKERS`) is replaced: any other folder is left alone;
    - a file output may be missing; an existing file is replaced only with ``overwrite``; a folder where a
      file is expected (or a file where a folder is expected) is refused;
    - every existing ancestor of the output must be a folder.

    Parameters
    ----------
    path : the output (file or folder); kind : a key of OUTPUT_MARKERS for folders, a word for files
    inputs : paths the command reads (None entries ignored)
    folder : whether the output is a folder

    Raises
    ------
    PanovoccError naming the output, exit status 2.
    """
    path = Path(path)
    check_output_path(path, folder)
    out = _resolved(path)
    for inp in inputs:
        if inp is None:
            continue
        src = _resolved(inp)
        if out == src or (folder and _is_within(src, out)) or _same_file(path, inp):
            raise PanovoccError(f"output would overwrite the input {inp}; choose another output path", path)
        if _is_within(out, src):
            raise PanovoccError(f"output lies inside the input {inp}; choose an output path outside it", path)
    if not (path.exists() or path.is_symlink()):
        return
    if folder:
        if not path.is_dir():
            raise PanovoccError(f"exists and is not a folder (expected a {kind} output folder)", path)
        if all(c.name in IGNORED_IN_EMPTY for c in path.iterdir()):
            return
        if not overwrite:
            if kind == "map" and is_output_of_kind(path, kind):
                raise PanovoccError("already holds a map (use --resume to continue it, --overwrite to start over)",
                                    path)
            raise PanovoccError("already exists and is not empty (pass --overwrite to replace a previous "
                                f"{kind} output)", path)
        if not is_output_of_kind(path, kind):
            raise PanovoccError(f"is not a panovocc {kind} output (no {OUTPUT_MARKERS[kind][0]}); refusing to "
                                "replace it even with --overwrite: remove it yourself or choose another path", path)
    else:
        if path.is_dir():
            raise PanovoccError(f"is a folder; expected a {kind} file path", path)
        owner = _data_owner(path) if overwrite else None
        if owner is not None:
            raise PanovoccError(f"is a file of the panovocc {owner[0]} {owner[1]}; refusing to replace it even with "
                                "--overwrite: choose an output path outside it", path)
        if not overwrite:
            raise PanovoccError("already exists (pass --overwrite to replace it)", path)


def check_outputs(outputs, overwrite: bool = False, inputs=()) -> None:
    """:func:`check_output` on every output of a command that writes several, and refuse two at one path.

    Parameters
    ----------
    outputs : (path, kind, folder) triples; a None path is skipped
    overwrite, inputs : as for :func:`check_output`

    Raises
    ------
    PanovoccError naming the output given twice (exit status 2).
    """
    seen: dict[Path, str] = {}
    for path, kind, folder in outputs:
        if path is None:
            continue
        key = _resolved(path)
        if key in seen:
            raise PanovoccError(f"given as two outputs ({seen[key]} and {kind}); one would replace the other: choose "
                                "different paths", path)
        seen[key] = kind
        check_output(path, kind, overwrite, inputs=inputs, folder=folder)


def clean_temporaries(folder: str | Path, names=()) -> list[Path]:
    """Remove atomic-write temporaries a killed run left in ``folder``: ``.STEM.*SUFFIX`` for each name.

    Call it only while holding the folder's lock (no other writer can own them). Returns what was removed.
    """
    folder = Path(folder)
    removed = []
    for name in names:
        p = Path(name)
        for tmp in folder.glob(f".{p.stem}.*{p.suffix}"):
            if tmp.is_file():
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed
