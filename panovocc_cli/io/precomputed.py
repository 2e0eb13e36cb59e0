"""Precomputed segmenter scores on disk (``precomputed:DIR``): what another model wrote, per frame.

Format (documented in docs/semantics.md)::

    DIR/vocab.json        ["wall", "floor", ...]   the C class names the scores are over
    DIR/<stem>.npz        "logits" (H, W, C) float16/float32, or "probs" (H, W, C) float16/float32
                          (probabilities, each pixel summing to 1 within 1e-2)
    DIR/<stem>.png        or: (H, W) uint8/uint16 ids into vocab.json; the dtype's maximum (255 or
                          65535) = no prediction (a flat distribution)
    DIR/<stem>_conf.png   optional with a label PNG: (H, W) uint8 confidence, value / 255
                          (default 0.9): the labelled class gets it, the others share the rest

``<stem>`` is the frame's zero-padded index (``000042``). When both exist, the ``.npz`` wins. Turning
these into log-probabilities over a user's vocabulary is :mod:`panovocc_cli.semantics.precomputed`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..classes import canonical_name
from ..config import PROB_TOL
from ..errors import PanovoccError
from ..frame import logits_stride
from .atomic import write_text
from .images import read_image, write_png
from .jsonfile import read_json
from .npz import check_npz, write_npz
from .sequence import frame_stem

DEFAULT_LABEL_CONFIDENCE = 0.9


@dataclass
class FrameScores:
    """One frame's stored scores (see :func:`read_frame_scores`)."""

    kind: str  # "logits", "probs" or "labels"
    array: np.ndarray
    confidence: np.ndarray | None = None
    none_id: int = -1


def read_vocab_json(folder: str | Path) -> list[str]:
    """The class names of a precomputed folder (``DIR/vocab.json``), canonical, non-empty, unique."""
    path = Path(folder) / "vocab.json"
    if not Path(folder).is_dir():
        raise PanovoccError("precomputed segmentation folder not found", folder)
    names = read_json(path, "the list of class names the scores are over")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
        raise PanovoccError("expected a non-empty JSON list of class-name strings", path)
    canon = [canonical_name(n) for n in names]
    if len(set(canon)) != len(canon):
        raise PanovoccError("class names repeat (after lower-casing and aliasing)", path)
    return canon


def _stride_to(stored_hw: tuple, shape: tuple | None) -> int:
    """1 when the stored scores have the frame's size (or no size is asked), the pixel stride s when the
    frame was given at a stride (the map's semantic stride: scores of pixels (s i, s j) are taken), else 0."""
    if shape is None or tuple(stored_hw) == tuple(shape):
        return 1
    return logits_stride(stored_hw, shape)


def read_frame_scores(folder: str | Path, stem: str, n_classes: int, shape: tuple[int, int] | None) -> FrameScores:
    """One frame's scores as stored, validated against ``n_classes`` and the frame ``shape`` ``(H, W)``
    (stored at full size for a ``shape`` that samples it at an integer stride: those pixels' scores).

    Returns a :class:`FrameScores`: ``kind`` ``"logits"`` or ``"probs"`` with ``array`` (H, W, C) float32,
    or ``kind`` ``"labels"`` with ``array`` (H, W) int64 ids, ``confidence`` (H, W) float32 in [0, 1]
    and ``none_id`` (the dtype's maximum: no prediction).
    """
    folder = Path(folder)
    npz = folder / f"{stem}.npz"
    png = folder / f"{stem}.png"
    if npz.is_file():
        check_npz(npz, "an .npz holding a (H, W, C) array 'logits' or 'probs'")
        try:
            with np.load(npz, allow_pickle=False) as z:
                keys = set(z.files)
                key = "logits" if "logits" in keys else "probs" if "probs" in keys else None
                if key is None:
                    raise PanovoccError(f"expected an array 'logits' or 'probs', found {sorted(keys)}", npz)
                a = z[key]
        except PanovoccError:
            raise
        except Exception as e:  # corrupt zip, pickled object arrays...
            raise PanovoccError(f"cannot read ({type(e).__name__}: {e})", npz) from None
        if a.dtype not in (np.float16, np.float32, np.float64):
            raise PanovoccError(f"'{key}' must be float16/float32, got {a.dtype}", npz)
        if a.ndim != 3:
            raise PanovoccError(f"'{key}' must be (H, W, C), got shape {a.shape}", npz)
        s = _stride_to(a.shape[:2], shape)
        if not s:
            raise PanovoccError(f"'{key}' is {a.shape[1]}x{a.shape[0]}, the frame is {shape[1]}x{shape[0]}", npz)
        a = a[::s, ::s]
        if a.shape[2] != n_classes:
            raise PanovoccError(f"'{key}' has {a.shape[2]} classes, vocab.json has {n_classes}", npz)
        a = a.astype(np.float32)
        if not np.isfinite(a).all():
            raise PanovoccError(f"'{key}' contains NaN or infinite values", npz)
        if key == "probs" and (a.min() < -PROB_TOL or a.max() > 1 + PROB_TOL
                               or np.abs(a.sum(axis=-1) - 1).max() > PROB_TOL):
            raise PanovoccError("'probs' must be in [0, 1] and sum to 1 over classes at every pixel", npz)
        return FrameScores(key, a)
    if png.is_file():
        raw = read_image(png, "unchanged")
        if raw.ndim != 2 or raw.dtype not in (np.uint8, np.uint16):
            raise PanovoccError(f"label image must be single-channel uint8/uint16, got {raw.dtype} {raw.shape}", png)
        s = _stride_to(raw.shape, shape)
        if not s:
            raise PanovoccError(f"labels are {raw.shape[1]}x{raw.shape[0]}, the frame is {shape[1]}x{shape[0]}", png)
        lab = raw.astype(np.int64)
        none_id = int(np.iinfo(raw.dtype).max)
        bad = (lab >= n_classes) & (lab != none_id)
        if bad.any():
            raise PanovoccError(f"label id {int(lab[bad].max())} but vocab.json has {n_classes} classes", png)
        conf_path = folder / f"{stem}_conf.png"
        if conf_path.is_file():
            conf = read_image(conf_path, "unchanged")
            if conf.dtype != np.uint8 or conf.shape != lab.shape:
                raise PanovoccError(f"confidence must be a uint8 image of shape {lab.shape}, got {conf.dtype} "
                                    f"{conf.shape}", conf_path)
            c = conf.astype(np.float32) / 255.0
        else:
            c = np.full(lab.shape, DEFAULT_LABEL_CONFIDENCE, dtype=np.float32)
        return FrameScores("labels", lab[::s, ::s], c[::s, ::s], none_id)
    raise PanovoccError(f"frame {stem} not found (expected {stem}.npz or {stem}.png)", folder)


def _write_vocab(folder: Path, vocab: Sequence[str]) -> None:
    names = [canonical_name(v) for v in vocab]
    path = folder / "vocab.json"
    if path.is_file():
        if read_vocab_json(folder) != names:
            raise PanovoccError(f"vocab.json already lists other classes than {names}", path)
        return
    write_text(path, json.dumps(names) + "\n")


def write_precomputed(folder: str | Path, stem: str | int, logits: np.ndarray, vocab: Sequence[str],
                      kind: str = "logits", dtype=np.float16) -> Path:
    """Write one frame of precomputed scores (and ``vocab.json`` if absent), atomically.

    Parameters
    ----------
    folder : path, created if needed
    stem : str or int, the frame stem (an int is zero-padded like sequence frames)
    logits : (H, W, C) float, logits (``kind="logits"``) or probabilities (``kind="probs"``)
    vocab : sequence of str, the C class names; must match an existing vocab.json
    kind : ``"logits"`` or ``"probs"``
    dtype : float16 (default, half the size) or float32

    Returns
    -------
    path : Path of the ``.npz`` written
    """
    folder = Path(folder)
    a = np.asarray(logits)
    if kind not in ("logits", "probs"):
        raise PanovoccError(f"kind must be 'logits' or 'probs', got {kind!r}")
    if a.ndim != 3 or a.shape[2] != len(vocab):
        raise PanovoccError(f"scores must be (H, W, {len(vocab)}), got {a.shape}")
    folder.mkdir(parents=True, exist_ok=True)
    _write_vocab(folder, vocab)
    stem = frame_stem(stem) if isinstance(stem, (int, np.integer)) else str(stem)
    path = folder / f"{stem}.npz"
    write_npz(path, {kind: a.astype(dtype)})
    return path


def write_precomputed_labels(folder: str | Path, stem: str | int, labels: np.ndarray, vocab: Sequence[str],
                             confidence: np.ndarray | None = None) -> Path:
    """Write one frame as a label PNG (ids into ``vocab``) with an optional uint8 confidence PNG.

    Parameters
    ----------
    labels : (H, W) int, ids into ``vocab`` (the dtype's maximum = no prediction)
    confidence : (H, W) float in [0, 1] or None
    """
    folder = Path(folder)
    lab = np.asarray(labels)
    dtype = np.uint8 if len(vocab) < 255 else np.uint16
    if lab.ndim != 2 or lab.min() < 0 or (lab.max() >= len(vocab) and lab.max() != np.iinfo(dtype).max):
        raise PanovoccError(f"labels must be (H, W) ids into the {len(vocab)} vocabulary words")
    folder.mkdir(parents=True, exist_ok=True)
    _write_vocab(folder, vocab)
    stem = frame_stem(stem) if isinstance(stem, (int, np.integer)) else str(stem)
    path = folder / f"{stem}.png"
    write_png(path, lab.astype(dtype))
    if confidence is not None:
        c = np.asarray(confidence, dtype=np.float64)
        if c.shape != lab.shape:
            raise PanovoccError(f"confidence must have the labels' shape {lab.shape}, got {c.shape}")
        write_png(folder / f"{stem}_conf.png", np.round(np.clip(c, 0, 1) * 255).astype(np.uint8))
    return path
