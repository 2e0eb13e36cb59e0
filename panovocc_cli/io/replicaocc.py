"""FreeOcc / ReplicaOcc / EmbodiedOcc scene-level ground truth ``global_occ_package/<scene>.pkl`` <-> grid.

The file is a pickled dict. FreeOcc's loader (``load_full_scene_occ`` in FreeOcc's
``src/scannet_utils/dataloader.py``) reads four keys and ignores the rest:

===================  ============================  ==================================================
key                  shape, type                   meaning
===================  ============================  ==================================================
``scene_dim``        (3,) integers                 grid size in voxels, (X, Y, Z)
``global_labels``    (X, Y, Z) integers            0 free, 255 unknown (ignored in scoring), else
                                                   1 + the line number of the class in FreeOcc's
                                                   ``replica_name.txt`` (:data:`REPLICA_NAMES`)
``global_pts``       (X, Y, Z, 3) float            world coordinates (metres) of each voxel's centre
``global_mask``      (X, Y, Z) bool                a validity mask; FreeOcc's scoring does not use it
``valid_img_paths``  list of str, optional         frames the scene was built from
===================  ============================  ==================================================

No voxel size is stored (0.08 m is passed beside the file); the grid's origin is the per-axis minimum
of ``global_pts``. Reading also accepts the **flat** form (``global_labels`` (N,), ``global_pts``
(N, 3): only the listed voxels, the rest unknown), Python lists wherever arrays are, any integer label
dtype, and two keys this toolkit adds when writing: ``voxel_size`` and ``class_names``.

Centres are snapped onto the global lattice (``centre / h - 0.5`` whole); a file whose centres are
off it by more than ``tol_m`` is refused unless ``allow_shift`` is set (the whole grid is then moved
by the common sub-voxel offset, which is reported). In the dense form, ``global_pts[i, j, k]`` must be
the centre of voxel ``origin + (i, j, k)``: FreeOcc compares grids by array index, so a file laid out
otherwise (axes permuted) is refused rather than silently re-ordered.

Class names: the user's list names ids ``1, 2, ...`` (id 0 free) unless its first entry is
``empty``/``free``/``unlabeled`` (then ids ``0, 1, ...``); without a list, the file's
``class_names`` key, else FreeOcc's Replica list (:data:`REPLICA_NAMES`). Our grid keeps the ids and
carries ``["empty", canonical names...]``.

Writing (:func:`write_replicaocc`) produces the dense form FreeOcc's loader reads, by default with
FreeOcc's Replica ids (classes not in that list become 254: occupied, no class), and, for a
prediction, unknown (255) written as 0 (FreeOcc's scripts count every label > 0 as occupied).

Security: a pickle can run code. Files are read with :class:`SafeUnpickler`, which builds only numpy
arrays, dtypes and scalars and plain builtin containers and numbers, and refuses anything else.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Sequence

import numpy as np

from ..classes import EMPTY, canonical_name
from ..config import DEFAULT_VOXEL_SIZE, SNAP_TOL
from ..errors import PanovoccError
from ..geometry.lattice import index_to_center
from ..grid import MAX_CLASSES, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from .atomic import atomic_path, check_output_path

FREE_NAMES = ("empty", "free", "unlabeled", "unlabelled")
DEFAULT_SNAP_TOL = SNAP_TOL  # fraction of a voxel a centre may be off the lattice (config.py)
PICKLE_PROTOCOL = 4  # what we write: readable by Python >= 3.4, same grid -> same bytes
MAX_VOXELS = 2_000_000_000

#: FreeOcc's ``src/scannet_utils/replica_name.txt``: the label id of ``REPLICA_NAMES[k]`` is ``k + 1``.
REPLICA_NAMES: tuple[str, ...] = tuple("""
backpack base-cabinet basket bathtub beam beanbag bed bench bike bin blanket blinds book bottle box bowl
camera cabinet candle chair chopping-board clock cloth clothing coaster comforter computer-keyboard cup
cushion curtain ceiling cooktop countertop desk desk-organizer desktop-computer door exercise-ball faucet
floor handbag hair-dryer handrail indoor-plant knife-block kitchen-utensil lamp laptop major-appliance mat
microwave monitor mouse nightstand pan panel paper-towel phone picture pillar pillow pipe plant-stand plate
pot rack refrigerator remote-control scarf sculpture shelf shoe shower-stall sink small-appliance sofa
stair stool switch table table-runner tablet tissue-paper toilet toothbrush towel tv-screen tv-stand
umbrella utensil-holder vase vent wall wall-cabinet wall-plug wardrobe window rug logo bag set-of-clothing
""".split())
assert len(REPLICA_NAMES) == 101

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
    """Load a pickle through :class:`SafeUnpickler`; any failure becomes one :class:`PanovoccError` line."""
    path = Path(path)
    if path.is_dir():
        raise PanovoccError("is a folder (expected a ReplicaOcc .pkl file)", path)
    if not path.is_file():
        raise PanovoccError("file not found (expected a ReplicaOcc .pkl file)", path)
    try:
        with open(path, "rb") as f:
            return SafeUnpickler(f).load()
    except MemoryError:
        raise PanovoccError("cannot read pickle (out of memory: not a ReplicaOcc file?)", path) from None
    except Exception as e:  # UnpicklingError, EOFError (truncated), ValueError, ...
        msg = str(e).splitlines()[0] if str(e) else ""
        raise PanovoccError(f"cannot read pickle ({type(e).__name__}: {msg})", path) from None


def parse_class_names(spec: str | Path | Sequence[str]) -> list[str]:
    """Class names from a list, ``replica`` (FreeOcc's list), a comma-separated string, or a text file.

    A text file has one name a line; ``#`` starts a comment.
    """
    if not isinstance(spec, (str, Path)):
        return [str(s).strip() for s in spec]
    if isinstance(spec, str) and spec.strip().lower() == "replica":
        return list(REPLICA_NAMES)
    p = Path(spec)
    if p.is_file():
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise PanovoccError("class-name file is not UTF-8 text", p) from None
        lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
        names = [ln for ln in lines if ln]
    else:
        if str(spec).endswith(".txt"):
            raise PanovoccError("class-name file not found", p)
        names = [s.strip() for s in str(spec).split(",") if s.strip()]
    if not names:
        raise PanovoccError(f"no class names in {str(spec)!r} (expected a file, 'replica' or a comma-separated list)")
    return names


def grid_class_names(user_names: Sequence[str]) -> list[str]:
    """Our grid's class_names (``["empty", ...]``) for the user's list, with ids kept (see module doc)."""
    names = [canonical_name(n) for n in user_names]
    if names and names[0] in FREE_NAMES:
        names = names[1:]
    out = [EMPTY] + names
    if len(out) > MAX_CLASSES:
        raise PanovoccError(f"{len(out)} classes; at most {MAX_CLASSES} fit in a uint8 grid")
    seen: dict[str, int] = {}
    for k, n in enumerate(out[1:], start=1):
        if n in seen:
            raise PanovoccError(f"class name {n!r} is given twice (ids {seen[n]} and {k}); names must be unique")
        seen[n] = k
    return out


def _file_voxel_size(data: dict, path) -> float | None:
    v = data.get("voxel_size")
    if v is None:
        return None
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
        if a.size != 1:
            raise ValueError
        h = float(a[0])
    except (TypeError, ValueError):
        raise PanovoccError(f"voxel_size must be one number of metres, got {v!r:.40}", path) from None
    if not (math.isfinite(h) and h > 0):
        raise PanovoccError(f"voxel_size must be a positive number of metres, got {h}", path)
    return h


def _int_labels(raw, path) -> np.ndarray:
    try:
        lab = np.asarray(raw)
    except (TypeError, ValueError) as e:
        raise PanovoccError(f"global_labels is not an array ({e})", path) from None
    if lab.dtype.kind == "f":
        if not np.all(np.isfinite(lab)) or not np.all(lab == np.round(lab)):
            raise PanovoccError(f"global_labels must be integers, got {lab.dtype} with fractions", path)
    elif lab.dtype.kind not in "iub":
        raise PanovoccError(f"global_labels must be integers, got {lab.dtype}", path)
    return lab.astype(np.int64)


def class_names_source(data, user_names: Sequence[str] | None) -> str:
    """Where the class names of a conversion come from: ``given``, ``file`` or ``replica`` (FreeOcc's list)."""
    if user_names is not None:
        return "given"
    if isinstance(data, dict) and isinstance(data.get("class_names"), (list, tuple)):
        return "file"
    return "replica"


def replicaocc_to_grid(data, user_names: Sequence[str] | None, voxel_size: float | None = None,
                       tol_m: float | None = None, allow_shift: bool = False,
                       path: str | Path | None = None) -> tuple[Grid, np.ndarray]:
    """Convert a loaded ReplicaOcc dict (dense or flat form) to a :class:`Grid`.

    Parameters
    ----------
    data : dict with ``global_labels`` (X, Y, Z) or (N,) integers and ``global_pts`` (X, Y, Z, 3) or
        (N, 3) metres (voxel centres); optional ``scene_dim`` (3,), ``global_mask``, ``voxel_size``,
        ``class_names``
    user_names : class names of the ids (module doc); None -> the file's ``class_names`` key, else
        FreeOcc's :data:`REPLICA_NAMES`
    voxel_size : metres; None -> the file's ``voxel_size`` key, else 0.08. Given and different from
        the file's key -> error.
    tol_m : metres a centre may be off the lattice; None -> a quarter voxel
    allow_shift : translate the grid by the common sub-voxel offset instead of refusing
    path : for messages

    Returns
    -------
    grid : Grid, uint8 labels; in the flat form unknown (255) where the file lists nothing
    shift : (3,) float64 metres added to every centre (zeros unless ``allow_shift`` was needed)
    """
    if not isinstance(data, dict):
        raise PanovoccError(f"expected a pickled dict (global_occ_package form), got {type(data).__name__}", path)
    missing = [k for k in ("global_labels", "global_pts") if k not in data]
    if missing:
        raise PanovoccError(f"missing keys {missing} (expected scene_dim, global_labels, global_pts, global_mask)",
                            path)
    file_h = _file_voxel_size(data, path)
    if voxel_size is not None:
        if not (math.isfinite(voxel_size) and voxel_size > 0):
            raise PanovoccError(f"voxel size must be a positive number of metres, got {voxel_size}", path)
        if file_h is not None and not np.isclose(file_h, voxel_size, rtol=1e-6):
            raise PanovoccError(f"file says voxel_size {file_h:g} m but {voxel_size:g} m was asked", path)
    h = float(voxel_size if voxel_size is not None else (file_h if file_h is not None else DEFAULT_VOXEL_SIZE))

    lab = _int_labels(data["global_labels"], path)
    try:
        pts = np.asarray(data["global_pts"], dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise PanovoccError(f"global_pts is not a numeric array ({str(e)[:80]})", path) from None
    dense = lab.ndim == 3 and pts.shape == lab.shape + (3,)
    flat = lab.ndim == 1 and pts.shape == (lab.shape[0], 3)
    if not (dense or flat):
        raise PanovoccError(f"global_pts has shape {pts.shape} and global_labels {lab.shape}; expected (X, Y, Z, 3) "
                            "with (X, Y, Z) (the dense form) or (N, 3) with (N,)", path)
    if lab.size == 0:
        raise PanovoccError("no voxels (global_labels is empty)", path)
    if not np.all(np.isfinite(pts)):
        raise PanovoccError("global_pts has non-finite values", path)
    dim = None
    if "scene_dim" in data:
        try:
            dim = np.asarray(data["scene_dim"], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise PanovoccError(f"scene_dim must be 3 integers, got {data['scene_dim']!r:.40}", path) from None
        if dim.size != 3 or not np.all(np.isfinite(dim)) or np.any(dim != np.round(dim)) or np.any(dim < 1):
            raise PanovoccError(f"scene_dim must be 3 positive integers, got {dim.tolist()}", path)
        dim = dim.astype(np.int64)
        if dense and tuple(dim) != lab.shape:
            raise PanovoccError(f"scene_dim is {dim.tolist()} but global_labels has shape {list(lab.shape)}", path)
    if "global_mask" in data:
        try:
            mask = np.asarray(data["global_mask"])
        except (TypeError, ValueError):
            mask = None
        if mask is None or mask.shape != lab.shape or mask.dtype.kind not in "biu":
            raise PanovoccError(f"global_mask must be a {'x'.join(map(str, lab.shape))} boolean array, got "
                                f"{getattr(mask, 'dtype', type(data['global_mask']).__name__)} "
                                f"{getattr(mask, 'shape', '')}", path)

    if user_names is None:
        if isinstance(data.get("class_names"), (list, tuple)):
            user_names = [str(n) for n in data["class_names"]]
        else:
            user_names = list(REPLICA_NAMES)
    names = grid_class_names(user_names)
    bad = (lab < 0) | ((lab >= len(names)) & (lab != UNKNOWN) & (lab != OCCUPIED_UNKNOWN_CLASS)) | (lab > UNKNOWN)
    if bad.any():
        raise PanovoccError(f"label id {int(lab[bad].reshape(-1)[0])} has no class name ({len(names) - 1} names "
                            "for ids 1..; 0 free, 255 unknown)", path)

    shape3 = lab.shape
    lab = lab.reshape(-1)
    pts = pts.reshape(-1, 3)
    tol = DEFAULT_SNAP_TOL * h if tol_m is None else float(tol_m)
    f = pts / h - 0.5
    idx = np.round(f)
    off = (f - idx) * h
    shift = np.zeros(3)
    if np.abs(off).max() > tol:
        if not allow_shift:
            raise PanovoccError(f"voxel centres are off the global lattice of {h:g} m by up to "
                                f"{np.abs(off).max():.4f} m (tolerance {tol:.4f} m); pass --allow-shift "
                                "to translate the grid onto it", path)
        shift = -np.median(off, axis=0)
        f = (pts + shift) / h - 0.5
        idx = np.round(f)
        if np.abs((f - idx) * h).max() > tol:
            raise PanovoccError("voxel centres do not share one sub-voxel offset: they are not a regular grid", path)
    idx = idx.astype(np.int64)
    i0 = idx.min(axis=0)  # FreeOcc's origin: the per-axis minimum of global_pts
    if dense:
        ijk = np.stack(np.unravel_index(np.arange(lab.size), shape3), axis=-1)
        wrong = np.any(idx - i0 != ijk, axis=1)
        if wrong.any():
            k = int(np.flatnonzero(wrong)[0])
            raise PanovoccError(f"global_pts{tuple(int(v) for v in ijk[k])} is the centre of voxel "
                                f"{(idx[k] - i0).tolist()} from the origin: the points are not laid out in "
                                "(x, y, z) index order", path)
        labels = lab.reshape(shape3).astype(np.uint8)
    else:
        shape = idx.max(axis=0) - i0 + 1
        if dim is not None and np.any(shape > dim):
            raise PanovoccError(f"points span {shape.tolist()} voxels but scene_dim is {dim.tolist()}", path)
        if np.prod(shape.astype(np.float64)) > MAX_VOXELS:
            raise PanovoccError(f"points span {shape.tolist()} voxels: too large for a dense grid", path)
        flat_idx = np.ravel_multi_index((idx - i0).T, tuple(shape))
        order = np.argsort(flat_idx, kind="stable")
        fs, ls = flat_idx[order], lab[order]
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


def replica_ids(grid: Grid) -> tuple[np.ndarray, list[str]]:
    """Label lookup table from the grid's ids to FreeOcc's Replica ids, matched by canonical name.

    Returns
    -------
    lut : (256,) uint8; 0, 254 and 255 map to themselves, class ``k`` to ``1 + REPLICA_NAMES.index``,
        a class missing from the Replica list to 254 (occupied, no class)
    unmatched : the grid's class names with no Replica id (written as 254)
    """
    replica = {canonical_name(n): k + 1 for k, n in enumerate(REPLICA_NAMES)}
    lut = np.arange(256, dtype=np.uint8)
    unmatched = []
    for k, raw in enumerate(grid.class_names[1:], start=1):
        n = canonical_name(raw)
        if n in replica:
            lut[k] = replica[n]
        else:
            lut[k] = OCCUPIED_UNKNOWN_CLASS
            unmatched.append(n)
    return lut, unmatched


def grid_to_replicaocc(grid: Grid, ids: str = "replica", prediction: bool = False) -> tuple[dict, list[str]]:
    """The dense ReplicaOcc dict of a grid, as FreeOcc's loader reads it.

    Parameters
    ----------
    grid : Grid
    ids : ``replica`` (FreeOcc's ids: 1 + line of ``replica_name.txt``, matched by canonical name) or
        ``own`` (the grid's ids unchanged)
    prediction : write unknown (255) as 0 (free): FreeOcc's scripts count any label > 0 as occupied

    Returns
    -------
    data : dict with ``scene_dim`` (3,) int64, ``global_labels`` (X, Y, Z) uint8, ``global_pts``
        (X, Y, Z, 3) float32 world centres in metres, ``global_mask`` (X, Y, Z) bool (the voxels the grid
        does not leave unknown), ``voxel_size`` float and ``class_names`` list[str] (names of ids 0..)
    unmatched : class names with no Replica id, written as 254 (``ids="replica"`` only)
    """
    if ids not in ("replica", "own"):
        raise PanovoccError(f"unknown id scheme {ids!r} (expected replica or own)")
    labels = grid.labels
    unmatched: list[str] = []
    if ids == "replica":
        lut, unmatched = replica_ids(grid)
        out = lut[labels]
        names = [EMPTY] + [canonical_name(n) for n in REPLICA_NAMES]
    else:
        out = labels.copy()
        names = list(grid.class_names)
    mask = labels != UNKNOWN
    if prediction:
        out[~mask] = 0
    shape = labels.shape
    ijk = np.stack(np.meshgrid(*(np.arange(s, dtype=np.int64) for s in shape), indexing="ij"), axis=-1)
    pts = grid.centers(ijk.reshape(-1, 3)).reshape(shape + (3,)).astype(np.float32)
    data = {
        "scene_dim": np.asarray(shape, dtype=np.int64),
        "global_labels": np.ascontiguousarray(out, dtype=np.uint8),
        "global_pts": pts,
        "global_mask": mask,
        "voxel_size": float(grid.voxel_size),
        "class_names": names,
    }
    return data, unmatched


def write_replicaocc(path: str | Path, grid: Grid, ids: str = "replica", prediction: bool = False) -> list[str]:
    """Atomically write a grid as a dense ReplicaOcc ``.pkl`` (protocol 4: same grid, same bytes).

    Returns the class names written as 254 (see :func:`grid_to_replicaocc`).
    """
    check_output_path(path, folder=False)
    grid.validate()
    data, unmatched = grid_to_replicaocc(grid, ids, prediction)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            pickle.dump(data, f, protocol=PICKLE_PROTOCOL)
    return unmatched
