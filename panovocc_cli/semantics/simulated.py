"""The simulated open-vocabulary segmenter (the embedded default).

Built from a frame's ground-truth labels, it produces the kind of per-pixel logits a real
open-vocabulary segmenter produces on an indoor ERP panorama. Frame ``i`` draws its noise from
``np.random.default_rng([seed, i])``, so a run is reproducible and each frame's errors differ.

Model of the logits ``L (H, W, C)`` of a pixel whose ground-truth class is ``g``:

* **clean logits** ``margin * sim(g, v)`` for each vocabulary word ``v``, from the similarity table of
  :mod:`.similarity`. A class in the vocabulary wins by a margin that is smaller against related
  classes (chair/sofa, table/cabinet, curtain/window, wall/door, bed/sofa, ceiling/lighting...).
  A class *outside* the vocabulary becomes the most similar vocabulary words (pillow -> bed or sofa,
  rug -> floor, blinds -> window or curtain) with a small margin, so the choice spreads; one with no
  similar word gets flat logits (a diffuse, low-confidence guess). Vocabulary words the simulator
  knows nothing about (not in the table, not a class of the sequence) sit ``unknown_bias`` below.
* **smooth random fields**: one unit-variance field per vocabulary word, Gaussian-interpolated from
  a coarse ``field_cells x 2 field_cells`` grid that wraps in longitude, scaled by
  ``field_sigma * (field_base + field_related * sim(g, v))`` so errors are spatially coherent blobs
  and fall preferably on related classes;
* **wrong blobs**: ``Poisson(blobs)`` ellipses per frame (wider in longitude toward the poles, as ERP
  stretches a region there), inside which each ground-truth class is pushed toward one confusion
  partner drawn from the similarity table (``blob_logit``, soft-edged);
* **latitude**: all noise is multiplied by ``1 + pole_gain |sin(phi)|^pole_power``, so errors grow
  toward the ERP poles;
* **eroded boundaries**: pixels within ``boundary_deg`` of a label boundary get up to ``boundary_logit``
  for the neighbouring region's class, decaying with distance and modulated along the boundary;
* **calibration**: the logits are divided by a per-frame temperature chosen (on a pixel sample) so
  that the mean maximum probability equals the frame's actual accuracy; because errors concentrate
  where margins are small, the maximum probability then tracks each pixel's chance of being right.

``noise`` scales every error term; ``noise = 0`` gives the clean logits (argmax = ground truth mapped
to the vocabulary, confidence >= 0.9 for an in-vocabulary class) and skips calibration.
Unlabeled pixels (id 0) get flat logits plus weak noise: a diffuse, low-confidence distribution.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from ..geometry.erp import latitudes
from .segmenter import FrameContext, Segmenter
from .similarity import is_known, similarity


@dataclass(frozen=True)
class SimulatedConfig:
    """Knobs of the simulated segmenter (logit units unless stated). See the module docstring."""

    noise: float = 1.0  # overall error scale; 0 = exact
    seed: int = DEFAULT_SEED
    margin: float = 6.0  # clean logit of the right class (related classes get margin * similarity)
    unknown_bias: float = -2.0  # clean logit of vocabulary words the simulator knows nothing about
    field_cells: int = 6  # coarse field grid rows (columns = 2x); 6 -> 30 degree cells
    field_sigma: float = 1.3  # std of the smooth per-class logit fields
    field_base: float = 0.5  # field amplitude factor for unrelated classes ...
    field_related: float = 1.0  # ... plus this times the similarity to the ground-truth class
    blobs: float = 4.0  # mean number of wrong-class ellipses per frame
    blob_size: tuple[float, float] = (0.04, 0.16)  # semi-axis range, fraction of the image height
    blob_logit: float = 7.0  # push toward the confusion partner at an ellipse's centre
    pole_gain: float = 1.5  # noise x (1 + pole_gain |sin phi|^pole_power)
    pole_power: float = 2.0
    boundary_deg: float = 2.5  # width of the eroded band along label boundaries, degrees of latitude
    boundary_logit: float = 6.0  # push toward the neighbour's class at the boundary itself
    unlabeled_noise: float = 0.3  # field scale on unlabeled (id 0) pixels
    calib_samples: int = 20000  # pixels used to fit the per-frame temperature


def clean_logit_table(class_names: Sequence[str], vocab: Sequence[str], cfg: SimulatedConfig) -> np.ndarray:
    """Clean logits of every ground-truth class over the vocabulary.

    Parameters
    ----------
    class_names : sequence of str, K names; entry 0 is ``unlabeled``
    vocab : sequence of str, C canonical names

    Returns
    -------
    table : (K, C) float32; row 0 (unlabeled) is flat zero
    """
    gt_known = {canonical_name(n) for n in class_names[1:]}
    k, c = len(class_names), len(vocab)
    table = np.zeros((k, c), dtype=np.float64)
    for i in range(1, k):
        for j, v in enumerate(vocab):
            table[i, j] = cfg.margin * similarity(class_names[i], v)
    unknown = np.array([not (is_known(v) or v in gt_known) for v in vocab])
    table[1:, unknown] += cfg.unknown_bias
    return table.astype(np.float32)


def similarity_matrix(class_names: Sequence[str], vocab: Sequence[str]) -> np.ndarray:
    """``(K, C)`` float32 similarities between ground-truth classes and vocabulary words (row 0 zero)."""
    s = np.zeros((len(class_names), len(vocab)), dtype=np.float32)
    for i in range(1, len(class_names)):
        for j, v in enumerate(vocab):
            s[i, j] = similarity(class_names[i], v)
    return s


def expected_labels(class_names: Sequence[str], vocab: Sequence[str]) -> np.ndarray:
    """What an exact segmenter calls each ground-truth class: ``(K,)`` int64 vocabulary index.

    A class in the vocabulary maps to itself; another to its most similar vocabulary word (ties: the
    first); -1 for ``unlabeled`` and for classes with no similar word.
    """
    s = similarity_matrix(class_names, vocab)
    top = np.argmax(s, axis=1).astype(np.int64)
    top[s.max(axis=1) <= 0] = -1
    top[0] = -1
    return top


def smooth_fields(rng: np.random.Generator, height: int, width: int, n: int, cells: int) -> np.ndarray:
    """``n`` unit-variance smooth random fields on the ERP image, periodic in longitude.

    Gaussian interpolation (std 0.6 cells) of iid normal values on a ``cells x 2 cells`` grid.

    Returns
    -------
    fields : (H, W, n) float32
    """
    gh, gw = max(1, int(cells)), max(2, 2 * int(cells))
    z = rng.standard_normal((n, gh, gw)).astype(np.float32)
    y = (np.arange(height) + 0.5) / height * gh
    x = (np.arange(width) + 0.5) / width * gw
    dv = y[:, None] - (np.arange(gh) + 0.5)[None, :]
    du = x[:, None] - (np.arange(gw) + 0.5)[None, :]
    du = (du + gw / 2.0) % gw - gw / 2.0
    av = np.exp(-0.5 * (dv / 0.6) ** 2)
    au = np.exp(-0.5 * (du / 0.6) ** 2)
    av /= np.sqrt((av ** 2).sum(axis=1, keepdims=True))
    au /= np.sqrt((au ** 2).sum(axis=1, keepdims=True))
    av, au = av.astype(np.float32), au.astype(np.float32)
    f = np.einsum("hi,nij->nhj", av, z)
    f = np.einsum("nhj,wj->hwn", f, au)
    return np.ascontiguousarray(f, dtype=np.float32)


def boundary_neighbours(labels: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Nearest different label within ``radius`` pixels along rows/columns (longitude wraps).

    Returns
    -------
    neighbour : (H, W) int64, the other region's id, or -1 where no boundary is within ``radius``
    dist : (H, W) int64, its distance in pixels (0 where none)
    """
    h, w = labels.shape
    nb = np.full((h, w), -1, dtype=np.int64)
    dist = np.zeros((h, w), dtype=np.int64)
    for d in range(1, radius + 1):
        for axis, step in ((1, d), (1, -d), (0, d), (0, -d)):
            if axis == 1:
                shifted = np.roll(labels, step, axis=1)
            else:
                shifted = np.empty_like(labels)
                if step > 0:
                    shifted[step:] = labels[:-step]
                    shifted[:step] = labels[:1]
                else:
                    shifted[:step] = labels[-step:]
                    shifted[step:] = labels[-1:]
            hit = (nb < 0) & (shifted != labels)
            nb[hit] = shifted[hit]
            dist[hit] = d
    return nb, dist


def _softmax_max(logits: np.ndarray) -> np.ndarray:
    m = logits.max(axis=-1, keepdims=True)
    e = np.exp(logits - m)
    return 1.0 / e.sum(axis=-1)


def fit_temperature(logits: np.ndarray, accuracy: float) -> float:
    """Temperature T such that the mean of ``max softmax(logits / T)`` equals ``accuracy``.

    Parameters
    ----------
    logits : (n, C) float32 sample of pixels
    accuracy : float in (0, 1], their measured accuracy

    Returns
    -------
    T : float in [0.05, 50]
    """
    c = logits.shape[1]
    target = float(np.clip(accuracy, 1.0 / c + 1e-3, 0.999))
    lo, hi = np.log(0.05), np.log(50.0)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if _softmax_max(logits / np.exp(mid)).mean() > target:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


class SimulatedSegmenter(Segmenter):
    """Ground-truth-based open-vocabulary segmenter with realistic, seeded errors."""

    def __init__(self, config: SimulatedConfig = SimulatedConfig()):
        self.config = config
        self.spec = "simulated"

    def logits(self, rgb: np.ndarray, vocab: Sequence[str], frame_index: int,
               context: FrameContext | None = None) -> np.ndarray:
        """Per-pixel logits ``(H, W, C)`` float32 (see :class:`Segmenter`); needs ``context.labels``."""
        if context is None or context.labels is None:
            raise PanovoccError("the simulated segmenter needs ground-truth labels (SEQ/semantic/); "
                                "use --segmenter precomputed:DIR for a sequence without them")
        labels = np.asarray(context.labels)
        if rgb is not None and tuple(np.shape(rgb)[:2]) != labels.shape:
            raise PanovoccError(f"frame {frame_index}: labels {labels.shape} and rgb {np.shape(rgb)[:2]} differ")
        return simulate_logits(labels, context.class_names, vocab, frame_index, self.config)


def simulate_logits(labels: np.ndarray, class_names: Sequence[str], vocab: Sequence[str], frame_index: int,
                    cfg: SimulatedConfig = SimulatedConfig()) -> np.ndarray:
    """Simulated segmenter output for one frame.

    Parameters
    ----------
    labels : (H, W) int, ground-truth ids into ``class_names`` (0 = unlabeled), ERP
    class_names : sequence of str, K names (entry 0 ``unlabeled``)
    vocab : sequence of str, C canonical names
    frame_index : int, selects the frame's noise (``default_rng([seed, frame_index])``)
    cfg : SimulatedConfig

    Returns
    -------
    logits : (H, W, C) float32
    """
    labels = np.asarray(labels, dtype=np.int64)
    if labels.ndim != 2:
        raise PanovoccError(f"ground-truth labels must be (H, W), got shape {labels.shape}")
    h, w = labels.shape
    k, c = len(class_names), len(vocab)
    if c == 0:
        raise PanovoccError("empty vocabulary")
    if labels.size and (labels.min() < 0 or labels.max() >= k):
        raise PanovoccError(f"label ids must lie in 0..{k - 1} (class_names has {k} entries)")
    table = clean_logit_table(class_names, vocab, cfg)
    logits = table[labels]  # (H, W, C)
    if cfg.noise <= 0:
        return np.ascontiguousarray(logits, dtype=np.float32)

    rng = np.random.default_rng([int(cfg.seed), int(frame_index)])
    sim = similarity_matrix(class_names, vocab)
    top = expected_labels(class_names, vocab)
    phi = latitudes(h)
    lat = (cfg.noise * (1.0 + cfg.pole_gain * np.abs(np.sin(phi)) ** cfg.pole_power)).astype(np.float32)

    # Smooth per-class fields, amplitude growing with relatedness to the ground-truth class.
    fields = smooth_fields(rng, h, w, c + 1, cfg.field_cells)
    amp = cfg.field_sigma * (cfg.field_base + cfg.field_related * sim)  # (K, C)
    amp[0, :] = cfg.field_sigma * cfg.unlabeled_noise
    logits += amp.astype(np.float32)[labels] * fields[..., :c] * lat[:, None, None]

    # Wrong-class ellipses: each ground-truth class pushed toward one confusion partner.
    n_blobs = rng.poisson(cfg.blobs * min(cfg.noise, 3.0))
    vv, uu = np.arange(h)[:, None], np.arange(w)[None, :]
    for _ in range(n_blobs):
        v0 = rng.uniform(0, h)
        u0 = rng.uniform(0, w)
        ra = rng.uniform(*cfg.blob_size) * h
        rb = rng.uniform(*cfg.blob_size) * h
        phi0 = np.pi / 2 - v0 / h * np.pi
        rb_u = min(rb / max(np.cos(phi0), 0.25), w / 2.0)
        partner = _blob_partners(rng, sim, top)
        v_lo, v_hi = max(0, int(v0 - ra)), min(h, int(v0 + ra) + 1)
        if v_hi <= v_lo:
            continue
        du = (uu - u0 + w / 2.0) % w - w / 2.0
        dv = vv[v_lo:v_hi] - v0
        r2 = (dv / ra) ** 2 + (du / rb_u) ** 2
        inside = r2 < 1.0
        if not inside.any():
            continue
        rows, cols = np.nonzero(inside)
        weight = (1.0 - r2[rows, cols]) ** 0.5
        rows = rows + v_lo
        tgt = partner[labels[rows, cols]]
        ok = tgt >= 0
        logits[rows[ok], cols[ok], tgt[ok]] += (cfg.blob_logit * cfg.noise * lat[rows[ok]] / lat.max()
                                                * weight[ok]).astype(np.float32)

    # Eroded boundaries: near a label boundary, the neighbouring region's class bleeds in.
    radius = max(1, int(round(cfg.boundary_deg / 180.0 * h)))
    nb, dist = boundary_neighbours(labels, radius)
    rows, cols = np.nonzero(nb > 0)
    if rows.size:
        tgt = top[nb[rows, cols]]
        ok = tgt >= 0
        rows, cols, tgt = rows[ok], cols[ok], tgt[ok]
        decay = 1.0 - (dist[rows, cols] - 1) / radius
        mod = np.exp(0.4 * fields[rows, cols, c])  # log-normal, median 1: erosion varies along the edge
        logits[rows, cols, tgt] += (cfg.boundary_logit * min(cfg.noise, 3.0) * decay * mod).astype(np.float32)

    # Calibration: one temperature per frame so that mean confidence = accuracy.
    if c > 1:
        exp_lab = top[labels]
        scored = np.flatnonzero(exp_lab.ravel() >= 0)
        if scored.size:
            if scored.size > cfg.calib_samples:
                scored = rng.choice(scored, cfg.calib_samples, replace=False)
            sample = logits.reshape(-1, c)[scored]
            acc = float((sample.argmax(axis=1) == exp_lab.ravel()[scored]).mean())
            if acc < 0.999:
                logits /= np.float32(fit_temperature(sample, acc))
    return np.ascontiguousarray(logits, dtype=np.float32)


def _blob_partners(rng: np.random.Generator, sim: np.ndarray, top: np.ndarray) -> np.ndarray:
    """For each ground-truth class, the vocabulary index an ellipse pushes it toward (-1: none)."""
    k, c = sim.shape
    partner = np.full(k, -1, dtype=np.int64)
    if c < 2:
        return partner
    for g in range(1, k):
        p = sim[g].astype(np.float64) + 0.05
        if top[g] >= 0:
            p[top[g]] = 0.0
        p /= p.sum()
        partner[g] = rng.choice(c, p=p)
    return partner
