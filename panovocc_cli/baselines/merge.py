"""The paper's rule for merging per-view-sequence predictions into one grid (no files here).

The paper (Sec. "Perspective Baseline Adaptation"): each perspective method runs once per view sequence;
"overlapping occupied predictions are combined by union, and semantic conflicts are resolved by class
voting for dense outputs and maximum class confidence for sparse outputs". Two functions, one per kind:

* :func:`merge_dense` -- label grids (CONVENTIONS.md grids, ReplicaOcc pickles once read): a voxel is
  occupied when any input says so; its class is the one most inputs give it (one vote per input that
  labels it with a class; 254 casts no vote); ties go to the class that comes first in the merged class
  list (deterministic). A voxel no input occupies is free (0) when some input saw it free, else 255.
* :func:`merge_sparse` -- scored voxels (:class:`SparseVoxels`): occupied = the union of the listed
  voxels; each voxel takes the class of its single most confident entry over all inputs (ties: the
  earlier input, then the smaller class position). Every other voxel of the merged box is predicted
  empty (0): a sparse output lists what it finds occupied and nothing else. An input that lists no voxel
  adds nothing; inputs that together list none are refused (there is no box to predict).

Both build a dense grid over the box of their inputs (:func:`merged_box`); :func:`merge_memory` is what that
grid costs, for a check before the merge (``baselines merge``).

Classes are matched by canonical name (:func:`panovocc_cli.classes.canonical_name`); the merged grid's
``class_names`` are ``"empty"`` then every input's names in order of first appearance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..classes import canonical_name
from ..config import VOXEL_SIZE_RTOL
from ..errors import PanovoccError
from ..geometry.lattice import index_to_center
from ..grid import EMPTY, MAX_CLASSES, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid


@dataclass
class SparseVoxels:
    """One sparse prediction: occupied voxels, each with a class and a confidence.

    index : (n, 3) int64 lattice indices (voxel n covers [n h, (n + 1) h) on each axis)
    labels : (n,) int64 positions in ``class_names`` (-1: occupied, no class)
    confidence : (n,) float64, the confidence of that class (any monotone score; compared across inputs)
    voxel_size : float, metres
    class_names : list of str, the classes ``labels`` index (no ``empty`` entry)
    """

    index: np.ndarray
    labels: np.ndarray
    confidence: np.ndarray
    voxel_size: float
    class_names: list


def merged_class_names(lists: Sequence[Sequence[str]]) -> list[str]:
    """``["empty", ...]``: the canonical names of ``lists`` (their ``empty`` entries dropped) in order of first
    appearance."""
    out: list[str] = ["empty"]
    for names in lists:
        for n in names:
            c = canonical_name(str(n))
            if c != "empty" and c not in out:
                out.append(c)
    if len(out) > MAX_CLASSES:
        raise PanovoccError(f"{len(out) - 1} distinct classes over the inputs; a grid holds at most {MAX_CLASSES - 1}")
    return out


def _check_voxel_sizes(sizes: Sequence[float]) -> float:
    h = float(sizes[0])
    for s in sizes[1:]:
        if not np.isclose(s, h, rtol=VOXEL_SIZE_RTOL, atol=0.0):
            raise PanovoccError(f"inputs have different voxel sizes ({h:g} m and {float(s):g} m); they must share "
                                "one lattice")
    return h


#: Bytes a voxel of the merged box costs while merging: dense (occupied, free and label arrays, and the
#: label copy written), sparse (the label array and its copy).
MERGE_BYTES_PER_VOXEL = {"dense": 4, "sparse": 2}


def _sparse_index(s: SparseVoxels) -> np.ndarray:
    return np.asarray(s.index, np.int64).reshape(-1, 3)


def merged_box(items: Sequence[Grid | SparseVoxels]) -> tuple[np.ndarray, tuple[int, ...]]:
    """First lattice index (3,) int64 and shape (3 ints) of the grid a merge of ``items`` covers: the union
    of the grids' boxes, or the box of every listed sparse voxel (raises when none is listed)."""
    if all(isinstance(x, SparseVoxels) for x in items):
        idx = np.concatenate([_sparse_index(s) for s in items]) if items else np.zeros((0, 3), np.int64)
        if len(idx) == 0:
            raise PanovoccError("the sparse inputs list no voxel: nothing occupied to merge")
        lo, hi = idx.min(axis=0), idx.max(axis=0) + 1
    else:
        lo = np.min([g.index0 for g in items], axis=0)
        hi = np.max([g.index0 + np.asarray(g.labels.shape) for g in items], axis=0)
    return lo, tuple(int(x) for x in hi - lo)


def merge_memory(items: Sequence[Grid | SparseVoxels], kind: str) -> tuple[tuple[int, ...], float]:
    """Shape of the merged grid and the bytes merging ``items`` (``kind`` dense | sparse) holds at once."""
    _, shape = merged_box(items)
    return shape, float(np.prod(np.asarray(shape, np.float64))) * MERGE_BYTES_PER_VOXEL[kind]


def _vote(flat: np.ndarray, cls: np.ndarray, score: np.ndarray, rank: np.ndarray, n_cls: int):
    """For each distinct ``flat`` position: the class with the highest ``score`` summed per (position, class)
    (``rank`` breaks ties: smaller wins). Returns (positions, classes)."""
    if len(flat) == 0:
        return flat, cls
    pair = flat * n_cls + cls
    uniq, inv = np.unique(pair, return_inverse=True)
    total = np.bincount(inv, weights=score)
    first_rank = np.full(len(uniq), np.iinfo(np.int64).max, np.int64)
    np.minimum.at(first_rank, inv, rank)
    pos, c = uniq // n_cls, uniq % n_cls
    order = np.lexsort((first_rank, -total, pos))  # by position, then most votes, then smallest rank
    pos_sorted = pos[order]
    keep = np.r_[True, pos_sorted[1:] != pos_sorted[:-1]]
    return pos_sorted[keep], c[order][keep]


def merge_dense(grids: Sequence[Grid]) -> Grid:
    """Merge label grids by union of occupancy and class voting (module docstring).

    Parameters
    ----------
    grids : sequence of Grid (same voxel size, any extents, any class lists)

    Returns
    -------
    Grid over the union of the inputs' boxes; ``class_names`` from :func:`merged_class_names`.
    """
    if not grids:
        raise PanovoccError("nothing to merge: no input grids")
    h = _check_voxel_sizes([g.voxel_size for g in grids])
    names = merged_class_names([g.class_names[1:] for g in grids])
    pos_of = {n: k for k, n in enumerate(names)}
    lo, shape = merged_box(grids)
    occupied = np.zeros(shape, bool)
    free = np.zeros(shape, bool)
    flats, classes = [], []
    for g in grids:
        sl = tuple(slice(int(a), int(a + n)) for a, n in zip(g.index0 - lo, g.labels.shape))
        lab = g.labels
        occ = (lab != EMPTY) & (lab != UNKNOWN)
        occupied[sl] |= occ
        free[sl] |= lab == EMPTY
        remap = np.full(256, -1, np.int64)
        for k, n in enumerate(g.class_names[1:], start=1):
            remap[k] = pos_of[canonical_name(n)]
        ijk = np.argwhere((lab != EMPTY) & (lab < OCCUPIED_UNKNOWN_CLASS))
        if len(ijk):
            c = remap[lab[tuple(ijk.T)]]
            gi = ijk + (g.index0 - lo)
            flats.append(np.ravel_multi_index(tuple(gi.T), shape))
            classes.append(c)
    labels = np.full(shape, UNKNOWN, np.uint8)
    labels[free] = EMPTY
    labels[occupied] = OCCUPIED_UNKNOWN_CLASS
    if flats:
        flat, cls = np.concatenate(flats), np.concatenate(classes)
        pos, c = _vote(flat, cls, np.ones(len(flat)), cls, len(names))
        labels.reshape(-1)[pos] = c.astype(np.uint8)
    return Grid(labels, index_to_center(lo, h), h, names)


def merge_sparse(inputs: Sequence[SparseVoxels]) -> Grid:
    """Merge sparse scored voxels by union of occupancy and maximum class confidence (module docstring).

    Returns
    -------
    Grid over the box of every listed voxel: listed voxels carry their class (254 when the most confident
    entry has none), the rest 0. Inputs that together list no voxel are refused (PanovoccError).
    """
    if not inputs:
        raise PanovoccError("nothing to merge: no sparse inputs")
    h = _check_voxel_sizes([s.voxel_size for s in inputs])
    names = merged_class_names([s.class_names for s in inputs])
    pos_of = {n: k for k, n in enumerate(names)}
    idx, cls, conf, order = [], [], [], []
    rank = 0
    for s in inputs:
        remap = np.array([pos_of[canonical_name(str(n))] for n in s.class_names] + [OCCUPIED_UNKNOWN_CLASS], np.int64)
        lab = np.asarray(s.labels, np.int64)
        idx.append(_sparse_index(s))
        cls.append(remap[np.where(lab < 0, len(s.class_names), lab)])
        conf.append(np.asarray(s.confidence, np.float64).reshape(-1))
        order.append(rank + np.arange(len(lab), dtype=np.int64))
        rank += len(lab)
    idx, cls, conf, order = (np.concatenate(a) for a in (idx, cls, conf, order))
    lo, shape = merged_box(inputs)
    flat = np.ravel_multi_index(tuple((idx - lo).T), shape)
    # the most confident entry of each voxel; ties: the earlier entry (input order, then listing order)
    o = np.lexsort((order, -conf, flat))
    f_sorted = flat[o]
    keep = np.r_[True, f_sorted[1:] != f_sorted[:-1]]
    labels = np.full(shape, EMPTY, np.uint8)
    labels.reshape(-1)[f_sorted[keep]] = cls[o][keep].astype(np.uint8)
    return Grid(labels, index_to_center(lo, h), h, names)
