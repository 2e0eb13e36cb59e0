"""The semantic side of ``panovocc map``: a per-frame semantic contributor and the labelled export.

Per frame, the segmenter (``simulated`` or ``precomputed:DIR``) gives logits over the run's vocabulary,
reduced once to the frame's :class:`~panovocc_cli.semantics.observation.SemanticObservation` (kept with the
frame's delta, so a revision never runs the segmenter again);
:func:`semantics.evidence.frame_semantic_delta` turns it into per-voxel float sums, which
:func:`quantize_semantic_delta` turns into integer memory channels that travel through the SAME delta
mechanism as the geometry (the delta log, ``revise``, ``--resume``: the memory stays the exact integer sum
of the retained deltas).

Channels (``C`` = vocabulary size), all exact integers. Per voxel and frame, with ``S_f`` the sum of the
pixels' weights eta, ``D`` their eta-weighted mean class distribution, ``k`` the pixel count and
``n_f``, ``c_f`` the sums of their normals and colours:

==============  =====  ============================================================================
name            width  per-frame delta
==============  =====  ============================================================================
``S``           1      ``64 s`` with ``s = round(256 S_f)``: the frame's weight in 1/256 steps
``E``           C      ``s d`` with ``d`` = ``64 D`` rounded to integers summing to 64 (largest
                       remainders): ``sum_c E = S``, so ``E / S`` is the weighted mean distribution
``normal_sum``  3      ``k round(127 n_f / k)``: the mean normal in 1/127 steps, times the count
``rgb_sum``     3      ``k round(c_f / k)``: the mean colour in grey levels, times the count
``count``       1      ``k``, pixels (measurements)
==============  =====  ============================================================================

Each channel is a product of small per-voxel factors, which the delta log stores instead of the products
(``io.mapstore``, factored channels: about a third of the bytes of the plain sums). The rounding is a
deviation from the paper's float sums, documented in docs/semantics.md ("Semantic observation and
evidence"); a weight below 1/512 in a voxel adds no class evidence there (its colour, normal and count
still count).

Overflow: a frame adds at most ``64 * 256 * (pixels in the voxel) * s^2`` to ``S`` (a whole 2048x1024 frame in
one voxel: 2^35); the memory widens int32 to int64 as needed and refuses sums past int64.

Export (:func:`label_occupied`): the occupied set comes from the geometry alone; over it,
``gsc.unaries`` (E/S, mean normal, mean colour), the mapper's signed score ``g`` and
``gsc.consolidate`` give a vocabulary index or -1 (grid label 254).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence as Seq

import numpy as np

from ..config import validate_config
from ..errors import PanovoccError
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from ..semantics.params import EvidenceWeights
from .config import (PLY_COLORS, SEGMENTER_AUTO, SEGMENTER_NONE, SegevalConfig,  # noqa: F401  (re-exports)
                     SemanticParams, mapper_gsc_params)
from .memory import ChannelSpec, Delta

UNCLASSED_COLOR = (160, 160, 160)  # map.ply colour of occupied voxels without a class


def resolve(p: SemanticParams, seq) -> SemanticParams:
    """Resolve ``auto``, the vocabulary and a precomputed folder; validate everything before any file is written.

    Parameters
    ----------
    p : SemanticParams as given by the user
    seq : io.sequence.Sequence, the sequence to be mapped

    Raises
    ------
    PanovoccError
        Empty/invalid vocabulary, unknown segmenter, negative noise, ``simulated`` (or ``auto``) on a
        sequence without ``semantic/`` labels, a precomputed folder that fails validation, bad ply_color.
    """
    from ..classes import parse_vocab
    from ..semantics.registry import build_segmenter, is_simulated

    if p.ply_color not in PLY_COLORS:
        raise PanovoccError(f"--ply-color must be one of {', '.join(PLY_COLORS)}, got {p.ply_color!r}")
    # an empty vocabulary is an error even for --segmenter none; 'all' = the sequence's classes
    vocab = parse_vocab(p.vocab, seq.meta.class_names if seq.has_labels else None, what="vocabulary (--vocab)")
    spec = p.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        if not seq.has_labels:
            raise PanovoccError("the sequence has no ground-truth labels (semantic/) for the default simulated "
                                "segmenter: pass --segmenter precomputed:DIR, or --segmenter none for geometry only",
                                seq.root)
        spec = "simulated"
    if spec == SEGMENTER_NONE:
        return dataclasses.replace(p, segmenter=SEGMENTER_NONE, vocab=[])
    if is_simulated(spec) and not seq.has_labels:
        raise PanovoccError("the simulated segmenter needs ground-truth labels (semantic/), which this sequence "
                            "lacks: pass --segmenter precomputed:DIR or --segmenter none", seq.root)
    if spec.startswith("precomputed:"):
        folder = spec[len("precomputed:"):]
        spec = "precomputed:" + (str(Path(folder).resolve()) if folder else "")
    seg = build_segmenter(spec, seed=int(p.seed), noise=float(p.noise))  # validates spec, noise, folder
    return dataclasses.replace(p, segmenter=seg.spec or spec, vocab=list(vocab))


S_STEPS = 256  # a frame's weight S_f in a voxel, in steps of 1 / S_STEPS
D_STEPS = 64  # its class distribution, in steps of 1 / D_STEPS (summing to D_STEPS)
NORMAL_STEPS = 127  # the mean normal's components, in steps of 1 / NORMAL_STEPS
S_SCALE = S_STEPS * D_STEPS  # stored S (and E) per unit of eta
DELTA_FACTORS = {"E": ("S", D_STEPS), "normal_sum": ("count", 1), "rgb_sum": ("count", 1)}
"""How each semantic channel of a frame's delta factors (``channel = factor * m / denominator``, m an integer
array): what the delta log stores instead of the product (:func:`panovocc_cli.io.mapstore.encode_delta`)."""


def semantic_channels(n_classes: int) -> tuple[ChannelSpec, ...]:
    """Memory channels of the semantic contributor for a vocabulary of ``n_classes`` words (all exact
    integers: the module docstring)."""
    return (ChannelSpec("E", n_classes, "int"), ChannelSpec("S", 1, "int"), ChannelSpec("rgb_sum", 3, "int"),
            ChannelSpec("normal_sum", 3, "int"), ChannelSpec("count", 1, "int"))


def distribution_steps(D: np.ndarray, steps: int = D_STEPS) -> np.ndarray:
    """Rows of a distribution ``D`` (n, C) float (non-negative, summing to ~1) in integer steps summing to
    exactly ``steps``: each ``steps * D`` rounded down, the remaining steps to the largest remainders (ties:
    the lower class). (n, C) int64; rows of ``D`` that sum to 0 stay 0."""
    D = np.asarray(D, np.float64)
    x = D * steps
    f = np.floor(x)
    rest = (steps - f.sum(axis=1)).astype(np.int64)
    rest = np.where(D.sum(axis=1) > 0, np.clip(rest, 0, D.shape[1]), 0)
    order = np.argsort(-(x - f), axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(D.shape[1])[None, :].repeat(len(D), axis=0), axis=1)
    return f.astype(np.int64) + (rank < rest[:, None])


def quantize_semantic_delta(keys: np.ndarray, channels: dict) -> Delta:
    """Float sums of :func:`semantics.evidence.frame_semantic_delta` -> the integer :class:`Delta` of the
    module docstring's table.

    keys : (n,) int64 sorted unique; channels : E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3)
    float64, count (n,) int64 (> 0)
    """
    S_f = np.asarray(channels["S"], np.float64).reshape(-1)
    count = np.asarray(channels["count"], np.int64).reshape(-1, 1)
    s = np.rint(S_f * S_STEPS).astype(np.int64)
    has = s > 0
    D = np.zeros(np.shape(channels["E"]), np.float64)
    D[has] = np.asarray(channels["E"], np.float64)[has] / S_f[has, None]
    d = distribution_steps(D)
    k = np.maximum(count, 1)
    normal = np.rint(np.asarray(channels["normal_sum"], np.float64) * NORMAL_STEPS / k).astype(np.int64)
    rgb = np.rint(np.asarray(channels["rgb_sum"], np.float64) / k).astype(np.int64)
    return Delta(keys, {"E": s[:, None] * d, "S": (D_STEPS * s)[:, None], "rgb_sum": count * rgb,
                        "normal_sum": count * normal, "count": count}, dict(DELTA_FACTORS))


def semantic_delta(depth: np.ndarray, rgb: np.ndarray, obs, T_world_cam: np.ndarray,
                   voxel_size: float, weights: EvidenceWeights, min_range: float, max_range: float,
                   rays: np.ndarray | None = None) -> Delta:
    """One frame's quantised semantic delta from its depth, colours and semantic observation (no I/O).

    Depths outside ``[min_range, max_range]`` (metres) are ignored, as in the geometry contributor.
    ``obs`` : :class:`~panovocc_cli.semantics.observation.SemanticObservation` at the semantic stride.
    """
    from ..semantics.evidence import frame_semantic_delta

    depth = np.where((depth >= min_range) & (depth <= max_range), depth, 0.0).astype(np.float32)
    keys, ch = frame_semantic_delta(depth, rgb, obs, T_world_cam, voxel_size, weights, rays)
    return quantize_semantic_delta(keys, ch)


def label_occupied(occupied_keys: np.ndarray, channels: dict, g: np.ndarray, params: SemanticParams) -> np.ndarray:
    """Vocabulary index of each occupied voxel, or -1 (no class; exported as 254).

    Parameters
    ----------
    occupied_keys : (n,) int64 voxel keys (lattice.pack_keys)
    channels : dict of the occupied voxels' stored channels, rows aligned with ``occupied_keys``:
        E (n, C), S (n, 1), normal_sum (n, 3), rgb_sum (n, 3), count (n, 1) int64 (module docstring)
    g : (n,) float64, the mapper's signed score (per-frame support units, ~0..1 on surfaces)
    params : SemanticParams (use_gsc, gsc)

    Returns
    -------
    labels : (n,) int64 in -1..C-1
    """
    from ..geometry.lattice import unpack_keys
    from ..semantics.gsc import consolidate, unaries
    n = len(occupied_keys)
    if n == 0:
        return np.zeros(0, np.int64)
    E = channels["E"] / S_SCALE
    S = channels["S"][:, 0] / S_SCALE
    p, normals, colors = unaries(E, S, channels["normal_sum"] / NORMAL_STEPS, channels["rgb_sum"],
                                 channels["count"][:, 0])
    return consolidate(unpack_keys(occupied_keys), p, S, np.asarray(g, np.float64), normals, colors,
                       use_gsc=params.use_gsc, params=params.gsc)


def apply_labels(grid: Grid, occupied_keys: np.ndarray, labels: np.ndarray, vocab: Seq[str]) -> Grid:
    """Write class labels into a three-state grid: occupied voxel -> 1 + label (254 where -1).

    The grid's class names become ``["empty"] + vocab``; free (0) and unobserved (255) voxels stay.
    """
    from ..geometry.lattice import unpack_keys

    out = grid.labels.copy()
    if len(occupied_keys):
        local = unpack_keys(occupied_keys) - grid.index0
        lab = np.asarray(labels, np.int64)
        out[tuple(local.T)] = np.where(lab >= 0, lab + 1, OCCUPIED_UNKNOWN_CLASS).astype(np.uint8)
    return Grid(out, grid.origin, grid.voxel_size, ["empty"] + list(vocab))


def class_colors(labels: np.ndarray, vocab: Seq[str]) -> np.ndarray:
    """(n, 3) uint8 colours: :func:`classes.class_color` of each label, grey for -1."""
    from ..classes import class_color

    table = np.array([class_color(c) for c in vocab] + [UNCLASSED_COLOR], np.uint8).reshape(-1, 3)
    lab = np.asarray(labels, np.int64)
    return table[np.where(lab >= 0, lab, len(vocab))]


# ---------------------------------------------------------------------------------------------
# Reference and diagnostics


def relabel_from_ground_truth(pred: Grid, gt: Grid, max_dist_vox: float = 0.0) -> Grid:
    """Reference "perfect labels" for a prediction's geometry: its occupied voxels labelled by the truth.

    Each occupied voxel of ``pred`` (label not 0/255) takes the ground-truth class at the same voxel when
    the truth has a class there (1..253). Elsewhere (the truth says empty, unknown or 254, or does not
    cover the voxel: a geometric false positive) it takes the class of the nearest ground-truth class
    voxel within ``max_dist_vox`` voxels (Euclidean), else 254.

    * ``max_dist_vox = 0``: the ceiling of any labelling of this occupied set under the FreeOcc protocol
      (a voxel the truth does not hold gets no class, so it adds no class false positive);
    * ``max_dist_vox = 2`` (the mapper's own transfer bound): what per-pixel ground-truth labels binned
      into the voxels give; a voxel of a thickened surface takes the class of the surface it belongs to,
      exactly as the mapper labels it from the pixels that fell into it.

    Free and unobserved voxels are unchanged.

    Parameters
    ----------
    pred, gt : Grid on the same lattice (same voxel size)
    max_dist_vox : float >= 0, voxels

    Returns
    -------
    Grid, ``pred``'s box, class names = ``gt.class_names``
    """
    from scipy.spatial import cKDTree

    from ..evaluation.align import check_same_voxel_size, resample_onto

    check_same_voxel_size(pred, gt, "prediction and ground truth")
    truth = resample_onto(gt, pred, fill=UNKNOWN)
    occ = (pred.labels != EMPTY) & (pred.labels != UNKNOWN)
    has_class = (truth != EMPTY) & (truth != UNKNOWN) & (truth != OCCUPIED_UNKNOWN_CLASS)
    out = pred.labels.copy()
    out[occ] = np.where(has_class[occ], truth[occ], OCCUPIED_UNKNOWN_CLASS)
    need = np.argwhere(occ & ~has_class)
    src = np.argwhere((gt.labels != EMPTY) & (gt.labels != UNKNOWN) & (gt.labels != OCCUPIED_UNKNOWN_CLASS))
    if max_dist_vox > 0 and len(need) and len(src):
        tree = cKDTree((src + gt.index0).astype(np.float64))
        dist, nn = tree.query((need + pred.index0).astype(np.float64), k=1,
                              distance_upper_bound=float(max_dist_vox) + 1e-9)
        ok = np.isfinite(dist)
        s_ijk = src[nn[ok]]
        out[tuple(need[ok].T)] = gt.labels[tuple(s_ijk.T)]
    return Grid(out, pred.origin, pred.voxel_size, list(gt.class_names))


def run_segeval(cfg: SegevalConfig, progress: bool = True):
    """Pooled 2D mIoU of the segmenter over frames ``0, every, 2 every, ...`` of ``cfg.seq``.

    Returns
    -------
    (Miou2D, frames) : the pooled result (.miou, .iou, .accuracy) and the scored frame indices

    Raises
    ------
    PanovoccError
        Bad ``every``, no labels, a bad vocabulary or class list, or a class list none of whose classes
        occur in the sequence's class names (a mean over no class).
    """
    from ..classes import canonical_name, parse_class_set, parse_vocab
    from ..io.sequence import Sequence
    from ..semantics.metrics2d import empty_scores, frame_scores
    from ..semantics.registry import build_segmenter
    from ..semantics.simulated import sequence_label_source

    cfg = validate_config(cfg)  # noise, seed, every: the ranges declared on SegevalConfig
    seq = Sequence(cfg.seq)
    if not seq.has_labels:
        raise PanovoccError("segeval needs ground-truth labels (semantic/)", seq.root)
    names = list(seq.meta.class_names)
    vocab = parse_vocab(cfg.vocab, names, what="vocabulary (--vocab)")
    classes = parse_class_set(cfg.classes, names)
    known = {canonical_name(n) for n in names[1:]}
    if not any(c in known for c in classes):
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the sequence's labels "
                            f"(its classes: {', '.join(sorted(known))})", seq.root / "meta.json")
    spec = cfg.segmenter.strip()
    if spec == SEGMENTER_AUTO:
        spec = "simulated"
    seg = build_segmenter(spec, seed=int(cfg.seed), noise=float(cfg.noise), label_source=sequence_label_source(seq))
    frames = list(range(0, len(seq), cfg.every))
    total = empty_scores(classes)
    it = frames
    if progress:
        from tqdm import tqdm

        it = tqdm(frames, desc="2D mIoU", unit="frame")
    for i in it:
        logits = seg.logits(seq.rgb(i), vocab, frame_id=i)
        total.add(frame_scores(np.argmax(logits, axis=-1), vocab, seq.labels(i), names, classes))
    if not total.present.any():
        raise PanovoccError(f"none of the classes {','.join(classes)} occur in the labels of the scored frames",
                            seq.root)
    return total, frames
