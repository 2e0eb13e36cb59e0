"""FreeOcc / ReplicaOcc scene-level ground truth (``global_occ_package/<scene>.pkl``) <-> grid ``.npz``.

Our reading of the format (a pickled dict; other keys are ignored):

==================  ==========================  ===================================================
key                 shape, type                 meaning
==================  ==========================  ===================================================
``global_labels``   (N,) integers               0 free, 255 unknown, other ids index a class-name
                                                list that the user supplies (not stored in the file)
``global_pts``      (N, 3) float                world coordinates (metres) of the voxel **centres**
``scene_dim``       (3,) integers               grid dimensions in voxels (checked: the points must
                                                fit in it)
``voxel_size``      float, optional             edge length in metres; else the caller's value
                                                (0.08 m, the benchmark's, by default)
==================  ==========================  ===================================================

Lists are accepted wherever arrays are. Centres are snapped onto the global lattice
(``centre / h - 0.5`` whole); a file whose centres are off it by more than ``tol_m`` is refused,
unless ``allow_shift`` is set, in which case the whole grid is translated by the (common) sub-voxel
offset, which is reported. Voxels the file does not list are unknown (255).

Class ids: the user's list names ids ``1, 2, ...`` in order (id 0 is free), unless its first entry
is ``empty``/``free``/``unlabeled``, in which case it names ids ``0, 1, ...``. Our grid keeps the
ids and carries ``["empty", canonical names...]``.

Security: a pickle can run code. It is read with :class:`SafeUnpickler`, which only lets numpy
arrays/dtypes/scalars and plain builtin containers and numbers be built and refuses anything else.
Writing back (:func:`write_replicaocc`) produces the same form: every voxel of the grid in C order,
``global_pts`` float32 centres, ``global_labels`` uint8, ``scene_dim`` int64, plus ``voxel_size``
and ``class_names`` keys.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Sequence

import numpy as np

from ..classes import EMPTY, canonical_name
from ..errors import PanovoccError
from ..geometry.lattice import index_to_center
from ..io.atomic import atomic_path
from ..grid import MAX_CLASSES, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

FREE_NAMES = ("empty", "free", "unlabeled", "unlabelled")
DEFAULT_SNAP_TOL = 0.25  # fraction of a voxel a centre may be off the lattice

_ALLOWED = {
    ("builtins", n) for n in ("dict", "list", "tuple", "set", "frozenset", "int", "float", "complex", "str",
                              "bytes", "bytearray", "bool", "slice", "range")
} | {
    (m, n)
    for m in ("numpy.core.multiarray", "numpy._core.multiarray")
    for n in ("_reconstruct", "scalar")
} | {
    ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.numeric", "_frombuffer"), ("collections", "OrderedDict"),
    ("_codecs", "encode"),  # protocol 2 stores bytes through it
}


class SafeUnpickler(pickle.Unpickler):
    """Unpickler that builds only numpy arrays, dtypes, scalars and builtin containers/numbers."""

    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED or (module == "numpy.dtypes" and name.endswith("DType")):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name} (only numpy arrays and builtins)")


def load_pickle(path: str | Path):
    """Load a pickle through :class:`SafeUnpickler`; errors become :class:`PanovoccError`."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("file not found", path)
    try:
        with open(path, "rb") as f:
            return SafeUnpickler(f).load()
    except Exception as e:  # UnpicklingError, EOFError, ValueError, ...
        raise PanovoccError(f"cannot read pickle ({type(e).__name__}: {e})", path) from None


def parse_class_names(spec: str | Path | Sequence[str]) -> list[str]:
    """Class names from a list, a comma-separated string, or a text file (one name a line, ``#`` comments)."""
    if not isinstance(spec, (str, Path)):
        return [str(s).strip() for s in spec]
    p = Path(spec)
    if p.is_file():
        lines = [ln.split("#", 1)[0].strip() for ln in p.read_text(encoding="utf-8").splitlines()]
        names = [ln for ln in lines if ln]
    else:
        if str(spec).endswith(".txt"):
            raise PanovoccError("class-name file not found", p)
        names = [s.strip() for s in str(spec).split(",") if s.strip()]
    if not names:
        raise PanovoccError(f"no class names in {str(spec)!r} (expected a file or a comma-separated list)")
    return names


def grid_class_names(user_names: Sequence[str]) -> list[str]:
    """Our grid's class_names (``["empty", ...]``) for the user's list, with ids kept (see module doc)."""
    names = [canonical_name(n) for n in user_names]
    if names and names[0] in FREE_NAMES:
        names = names[1:]
    out = [EMPTY] + names
    if len(out) > MAX_CLASSES:
        raise PanovoccError(f"{len(out)} classes; at most {MAX_CLASSES} fit in a uint8 grid")
    return out


def replicaocc_to_grid(data: dict, user_names: Sequence[str] | None, voxel_size: float | None = None,
                       tol_m: float | None = None, allow_shift: bool = False,
                       path: str | Path | None = None) -> tuple[Grid, np.ndarray]:
    """Convert a loaded ReplicaOcc dict to a :class:`Grid`.

    Parameters
    ----------
    data : dict with ``global_labels`` (N,), ``global_pts`` (N, 3) metres, ``scene_dim`` (3,)
    user_names : class names for the ids (see module doc); None -> the file's ``class_names`` key
        (present in files this toolkit wrote)
    voxel_size : metres; None -> the file's ``voxel_size`` key, else 0.08. Given and different from
        the file's key -> error.
    tol_m : how far (metres) a centre may be off the lattice; None -> a quarter voxel
    allow_shift : translate the grid by the common sub-voxel offset instead of refusing
    path : for messages

    Returns
    -------
    grid : Grid, uint8 labels, unknown (255) where the file lists nothing
    shift : (3,) float64 metres added to every centre (zeros unless ``allow_shift`` was needed)
    """
    if not isinstance(data, dict):
        raise PanovoccError(f"expected a pickled dict, got {type(data).__name__}", path)
    missing = [k for k in ("global_labels", "global_pts") if k not in data]
    if missing:
        raise PanovoccError(f"missing keys {missing} (expected global_labels, global_pts, scene_dim)", path)
    file_h = data.get("voxel_size")
    if file_h is not None:
        file_h = float(np.asarray(file_h).reshape(-1)[0])
        if voxel_size is not None and not np.isclose(file_h, voxel_size, rtol=1e-6):
            raise PanovoccError(f"file says voxel_size {file_h:g} m but {voxel_size:g} m was asked", path)
    h = float(voxel_size if voxel_size is not None else (file_h if file_h is not None else 0.08))
    if not h > 0:
        raise PanovoccError(f"voxel size must be positive, got {h}", path)
    try:
        lab = np.asarray(data["global_labels"]).reshape(-1)
        pts = np.asarray(data["global_pts"], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise PanovoccError(f"global_labels/global_pts are not numeric arrays ({e})", path) from None
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] != lab.shape[0]:
        raise PanovoccError(f"global_pts has shape {pts.shape}, expected ({lab.shape[0]}, 3) to match global_labels",
                            path)
    if lab.dtype.kind not in "iub":
        if lab.dtype.kind != "f" or not np.all(lab == np.round(lab)):
            raise PanovoccError(f"global_labels must be integers, got {lab.dtype}", path)
    lab = lab.astype(np.int64)
    if lab.size == 0:
        raise PanovoccError("no voxels (global_labels is empty)", path)
    if not np.all(np.isfinite(pts)):
        raise PanovoccError("global_pts has non-finite values", path)

    if user_names is None:
        if not isinstance(data.get("class_names"), (list, tuple)):
            raise PanovoccError("no class names given and the file carries none (pass --class-names)", path)
        user_names = [str(n) for n in data["class_names"]]
    names = grid_class_names(user_names)
    bad = (lab < 0) | ((lab >= len(names)) & (lab != UNKNOWN) & (lab != OCCUPIED_UNKNOWN_CLASS))
    if bad.any():
        raise PanovoccError(f"label id {int(lab[bad][0])} has no class name ({len(names) - 1} names given "
                            "for ids 1..; 0 free, 255 unknown)", path)

    tol = DEFAULT_SNAP_TOL * h if tol_m is None else float(tol_m)
    f = pts / h - 0.5
    idx = np.round(f)
    off = (f - idx) * h
    shift = np.zeros(3)
    if np.abs(off).max() > tol:
        if not allow_shift:
            raise PanovoccError(f"voxel centres are off the global lattice of {h:g} m by up to "
                                f"{np.abs(off).max():.4f} m (tolerance {tol:.4f} m); pass allow_shift "
                                "(--allow-shift) to translate the grid onto it", path)
        shift = -np.median(off, axis=0)
        f = (pts + shift) / h - 0.5
        idx = np.round(f)
        if np.abs((f - idx) * h).max() > tol:
            raise PanovoccError("voxel centres do not share one sub-voxel offset: they are not a regular grid", path)
    idx = idx.astype(np.int64)
    i0 = idx.min(axis=0)
    shape = idx.max(axis=0) - i0 + 1
    if "scene_dim" in data:
        dim = np.asarray(data["scene_dim"]).reshape(-1)
        if dim.size != 3 or np.any(shape > dim):
            raise PanovoccError(f"points span {shape.tolist()} voxels but scene_dim is {dim.tolist()}", path)
    if np.prod(shape) > 2_000_000_000:
        raise PanovoccError(f"points span {shape.tolist()} voxels: too large for a dense grid", path)
    local = idx - i0
    flat = np.ravel_multi_index(local.T, tuple(shape))
    order = np.argsort(flat, kind="stable")
    fs, ls = flat[order], lab[order]
    dup = fs[1:] == fs[:-1]
    if np.any(dup & (ls[1:] != ls[:-1])):
        raise PanovoccError("the same voxel is listed twice with different labels", path)
    labels = np.full(tuple(shape), UNKNOWN, dtype=np.uint8)
    labels.reshape(-1)[fs] = ls.astype(np.uint8)
    g = Grid(labels, index_to_center(i0, h), h, names)
    return g.validate(path), shift


def read_replicaocc(path: str | Path, user_names: Sequence[str] | None, voxel_size: float | None = None,
                    tol_m: float | None = None, allow_shift: bool = False) -> tuple[Grid, np.ndarray]:
    """Read a ``global_occ_package/<scene>.pkl`` into a Grid (see :func:`replicaocc_to_grid`)."""
    return replicaocc_to_grid(load_pickle(path), user_names, voxel_size, tol_m, allow_shift, path)


def grid_to_replicaocc(grid: Grid) -> dict:
    """The ReplicaOcc dict of a grid: every voxel in C order (unknown ones as 255).

    Returns
    -------
    dict with ``global_labels`` (N,) uint8, ``global_pts`` (N, 3) float32 metres (centres),
    ``scene_dim`` (3,) int64, ``voxel_size`` float, ``class_names`` list[str] (ids 0..K-1, 0 = empty)
    """
    shape = grid.labels.shape
    ijk = np.stack(np.unravel_index(np.arange(grid.labels.size), shape), axis=-1)
    return {
        "global_labels": grid.labels.reshape(-1).copy(),
        "global_pts": grid.centers(ijk).astype(np.float32),
        "scene_dim": np.asarray(shape, dtype=np.int64),
        "voxel_size": float(grid.voxel_size),
        "class_names": list(grid.class_names),
    }


def write_replicaocc(path: str | Path, grid: Grid) -> None:
    """Atomically write a grid as a ReplicaOcc ``.pkl`` (pickle protocol 4, deterministic bytes)."""
    grid.validate()
    data = grid_to_replicaocc(grid)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            pickle.dump(data, f, protocol=4)
