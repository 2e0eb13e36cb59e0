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
  for the neighbouring region's class, decaying linearly with the distance of the pixel's centre from the
  boundary (in degrees, so an image at half the resolution is eroded over the same angle, by the same
  amount) and modulated along the boundary;
* **confidence** (:class:`ConfidenceModel`): the logits are divided by a temperature
  ``T = temperature * exp(jitter * z)``, ``z ~ N(0, 1)`` drawn from the frame's seeded generator, so a
  frame is sometimes sharper, sometimes flatter, as a network's outputs are from image to image. The
  temperature is a fixed, documented parameter, never fitted to a frame's ground truth. Presets
  (``simulated:NAME`` on the command line): ``calibrated`` (default: ``T = 1.3``, jitter 0.15, the
  spread of the per-frame temperatures that made mean confidence equal accuracy on the reference
  scenes of seeds 0 and 1; over a scene, confidence then tracks accuracy) and ``overconfident``
  (``T = 0.5``: mean confidence well above accuracy, the usual behaviour of networks trained with
  cross-entropy); ``raw`` (``T = 1``, no jitter) leaves the logits as composed.

``noise`` scales every error term; ``noise = 0`` gives the clean logits (argmax = ground truth mapped
to the vocabulary, confidence >= 0.9 for an in-vocabulary class) and no temperature.
Unlabeled pixels (id 0) get flat logits plus weak noise: a diffuse, low-confidence distribution.

The simulator reads ground truth, so it is built with its label source
(:class:`SimulatedSegmenter` ``(label_source, ...)``: a callable ``frame_id -> (labels, class_names)``),
never handed labels through :meth:`Segmenter.logits`. The per-pixel work (field synthesis, class
logits, boundary search and erosion, temperature) runs in compiled numba kernels; the random draws stay
in numpy, in a fixed order, so a frame's output depends only on ``(seed, frame_id)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numba as nb
import numpy as np

from ..classes import canonical_name
from ..config import DEFAULT_SEED
from ..errors import PanovoccError
from ..frame import logits_stride
from ..geometry.erp import latitudes
from .segmenter import Segmenter
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
    confidence: str = "calibrated"  # temperature preset (CONFIDENCE_MODELS), see ConfidenceModel
    feature_noise: float = 0.5  # embedding mode: std of each pixel's Gaussian noise vector's length (x noise)


@dataclass(frozen=True)
class ConfidenceModel:
    """The simulated segmenter's confidence: frame temperature ``T = temperature * exp(jitter * z)``.

    ``z ~ N(0, 1)`` is drawn from the frame's generator ``default_rng([seed, frame_id])`` after every
    other draw; the logits are divided by ``T`` (``T > 1`` flattens, ``T < 1`` sharpens).
    """

    temperature: float
    jitter: float


CONFIDENCE_MODELS: dict[str, ConfidenceModel] = {
    # geometric mean and log-std of the per-frame temperatures that matched mean confidence to accuracy
    # on the reference scenes (synth seeds 0 and 1, 20 frames, 1024x512, eval8 + open4): 1.28, 0.16
    "calibrated": ConfidenceModel(1.3, 0.15),
    "overconfident": ConfidenceModel(0.5, 0.15),
    "raw": ConfidenceModel(1.0, 0.0),
}


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


LabelSource = Callable[[object], tuple[np.ndarray, Sequence[str]]]


class SimulatedSegmenter(Segmenter):
    """Ground-truth-based open-vocabulary segmenter with realistic, seeded errors.

    Parameters
    ----------
    label_source : callable ``frame_id -> (labels, class_names)``
        The simulator's ground truth: ``labels`` (H, W) int ids into ``class_names`` (entry 0
        ``unlabeled``), e.g. :func:`sequence_label_source`. None builds a segmenter that can be
        configured and saved but fails on :meth:`logits`.
    config : SimulatedConfig
    """

    def __init__(self, label_source: LabelSource | None = None, config: SimulatedConfig = SimulatedConfig()):
        if config.confidence not in CONFIDENCE_MODELS:
            raise PanovoccError(f"unknown confidence model {config.confidence!r}: expected one of "
                                f"{', '.join(CONFIDENCE_MODELS)}")
        self.config = config
        self.label_source = label_source
        self.spec = "simulated" if config.confidence == "calibrated" else f"simulated:{config.confidence}"

    def logits(self, rgb: np.ndarray, vocab: Sequence[str], *, frame_id=None) -> np.ndarray:
        """Per-pixel logits ``(H, W, C)`` float32 (see :class:`Segmenter`); ``frame_id`` (an int frame index)
        selects the labels and seeds the noise."""
        labels, class_names = self._labels(rgb, frame_id)
        return simulate_logits(labels, class_names, vocab, int(frame_id), self.config)

    def features(self, rgb: np.ndarray, *, frame_id=None) -> np.ndarray:
        """Embedding mode, a simulator: per-pixel features ``(H, W, F)`` float32 in the space of the packaged
        MiniLM text model (F = 384).

        A pixel's feature is the text model's embeddings of the sequence's class names weighted by the
        softmax of the simulated logits over all those names (:func:`simulate_logits`: the same smooth
        fields, wrong-class blobs, eroded boundaries and temperature as the class route, so confusions and
        boundary errors carry over), plus a seeded Gaussian vector of length about ``feature_noise * noise``
        (``default_rng([seed, frame_id, 24])``). An exact segmenter (noise 0) gives the true class's
        embedding. Queries in other words ("couch", "somewhere to sleep") are then answered through the same
        text model: honest as a simulator, not evidence of what a real network's features do."""
        from ..classes import canonical_name

        labels, class_names = self._labels(rgb, frame_id)
        words = list(dict.fromkeys(canonical_name(n) for n in class_names[1:]))
        lg = simulate_logits(labels, class_names, words, int(frame_id), self.config)
        lg = lg - lg.max(axis=2, keepdims=True)
        p = np.exp(lg)
        p /= p.sum(axis=2, keepdims=True)
        emb = self._embeddings(tuple(words))
        f = (p.reshape(-1, len(words)) @ emb).reshape(p.shape[:2] + (emb.shape[1],)).astype(np.float32)
        sd = self.config.feature_noise * self.config.noise / np.sqrt(emb.shape[1])
        if sd > 0:
            rng = np.random.default_rng([int(self.config.seed), int(frame_id), 24])
            f += np.float32(sd) * rng.standard_normal(f.shape, dtype=np.float32)
        return f

    def text_encoder(self):
        """The packaged MiniLM text model (:func:`.query.minilm_encoder`), the space of :meth:`features`."""
        if getattr(self, "_encode", None) is None:
            from .query import minilm_encoder

            self._encode = minilm_encoder()
        return self._encode

    def _embeddings(self, words: tuple) -> np.ndarray:
        """(K, F) float32 text embeddings of class names (once per name list)."""
        cache = self.__dict__.setdefault("_emb_cache", {})
        if words not in cache:
            from .query import _words

            cache[words] = np.asarray(self.text_encoder()([_words(w) for w in words]), np.float32)
        return cache[words]

    def _labels(self, rgb, frame_id):
        """The frame's ground-truth labels (at the pixels of ``rgb``: a stride) and class names."""
        if self.label_source is None:
            raise PanovoccError("the simulated segmenter needs ground-truth labels (SEQ/semantic/); "
                                "use --segmenter precomputed:DIR for a sequence without them")
        if frame_id is None:
            raise PanovoccError("the simulated segmenter needs a frame id (its labels and noise seed)")
        labels, class_names = self.label_source(frame_id)
        labels = np.asarray(labels)
        if rgb is not None and tuple(np.shape(rgb)[:2]) != labels.shape:
            s = logits_stride(labels.shape, np.shape(rgb)[:2])  # an image given at a pixel stride (the map's
            if not s:                                            # semantic stride): the labels of those pixels
                raise PanovoccError(f"frame {frame_id}: labels {labels.shape} and rgb {np.shape(rgb)[:2]} differ")
            labels = labels[::s, ::s]
        return labels, class_names


def sequence_label_source(seq) -> LabelSource:
    """The label source of a sequence folder (:class:`io.sequence.Sequence`): frame index -> its
    ``semantic/`` labels and the sequence's class names."""
    names = list(seq.meta.class_names)
    return lambda i: (seq.labels(int(i)), names)


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
    if cfg.confidence not in CONFIDENCE_MODELS:
        raise PanovoccError(f"unknown confidence model {cfg.confidence!r}: expected one of {', '.join(CONFIDENCE_MODELS)}")
    table = clean_logit_table(class_names, vocab, cfg)
    labels32 = np.ascontiguousarray(labels, dtype=np.int32)
    if cfg.noise <= 0:
        return _gather_rows(labels32, table)

    rng = np.random.default_rng([int(cfg.seed), int(frame_index)])
    sim = similarity_matrix(class_names, vocab)
    top = expected_labels(class_names, vocab)
    phi = latitudes(h)
    lat = (cfg.noise * (1.0 + cfg.pole_gain * np.abs(np.sin(phi)) ** cfg.pole_power)).astype(np.float32)

    # Smooth per-class fields, amplitude growing with relatedness to the ground-truth class.
    rows_f, cols_f = field_factors(rng, h, w, c + 1, cfg.field_cells)
    amp = cfg.field_sigma * (cfg.field_base + cfg.field_related * sim)  # (K, C)
    amp[0, :] = cfg.field_sigma * cfg.unlabeled_noise
    logits, last_field = _compose(labels32, table, amp.astype(np.float32), lat, rows_f, cols_f)

    # Wrong-class ellipses: each ground-truth class pushed toward one confusion partner.
    n_blobs = rng.poisson(cfg.blobs * min(cfg.noise, 3.0))
    for _ in range(n_blobs):
        v0 = rng.uniform(0, h)
        u0 = rng.uniform(0, w)
        ra = rng.uniform(*cfg.blob_size) * h
        rb = rng.uniform(*cfg.blob_size) * h
        phi0 = np.pi / 2 - v0 / h * np.pi
        rb_u = min(rb / max(np.cos(phi0), 0.25), w / 2.0)
        partner = _blob_partners(rng, sim, top)
        _add_blob(logits, labels32, partner, lat, float(lat.max()), v0, u0, ra, rb_u, cfg.blob_logit * cfg.noise)

    # Eroded boundaries: near a label boundary, the neighbouring region's class bleeds in.
    radius_f = cfg.boundary_deg / 180.0 * h  # the band's width in pixels of this image
    radius = max(1, int(np.floor(radius_f + 0.5)))  # pixels whose centre lies within it (at least 1)
    _erode_boundaries(logits, labels32, top, last_field, radius, radius_f, cfg.boundary_logit * min(cfg.noise, 3.0))

    # Confidence: a seeded frame temperature (never fitted to the frame's accuracy).
    model = CONFIDENCE_MODELS[cfg.confidence]
    z = rng.standard_normal()
    T = model.temperature * float(np.exp(model.jitter * z))
    if T != 1.0:
        _scale(logits, np.float32(1.0 / T))
    return logits


def field_factors(rng: np.random.Generator, height: int, width: int, n: int, cells: int):
    """Separable factors of :func:`smooth_fields`: field ``k`` at pixel (v, u) is
    ``sum_j rows[v, k, j] * cols[j, u]``.

    Returns
    -------
    rows : (H, n, gw) float32, the coarse values interpolated along latitude
    cols : (gw, W) float32, the longitude interpolation weights (periodic)
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
    rows = np.ascontiguousarray(np.einsum("hi,nij->hnj", av, z), dtype=np.float32)
    return rows, np.ascontiguousarray(au.T)


@nb.njit(cache=True, parallel=True)
def _gather_rows(labels, table):
    """``table[labels]``: (H, W, C) float32."""
    H, W = labels.shape
    C = table.shape[1]
    out = np.empty((H, W, C), np.float32)
    for v in nb.prange(H):
        for u in range(W):
            g = labels[v, u]
            for k in range(C):
                out[v, u, k] = table[g, k]
    return out


@nb.njit(cache=True, parallel=True)
def _compose(labels, table, amp, lat, rows_f, cols_t):
    """Clean logits plus the smooth fields: ``table[g] + amp[g] * field * lat[v]`` (float32) per pixel
    (rows in parallel; a row's fields are summed over the coarse columns, vectorised along the row).
    Returns the (H, W, C) logits and the last field (H, W), which modulates the boundary erosion."""
    H, W = labels.shape
    C = table.shape[1]
    G = cols_t.shape[0]
    out = np.empty((H, W, C), np.float32)
    last = np.empty((H, W), np.float32)
    for v in nb.prange(H):
        f = np.zeros((C + 1, W), np.float32)
        for k in range(C + 1):
            for j in range(G):
                r = rows_f[v, k, j]
                for u in range(W):
                    f[k, u] += r * cols_t[j, u]
        lv = lat[v]
        for u in range(W):
            g = labels[v, u]
            for k in range(C):
                out[v, u, k] = table[g, k] + amp[g, k] * f[k, u] * lv
            last[v, u] = f[C, u]
    return out, last


@nb.njit(cache=True)
def _add_blob(logits, labels, partner, lat, lat_max, v0, u0, ra, rb_u, push):
    """Push each pixel of the ellipse centred on (v0, u0) (semi-axes ra rows, rb_u columns, longitude
    wrapping) toward its class's confusion partner by ``push * lat[v] / lat_max * sqrt(1 - r^2)``."""
    H, W = labels.shape
    v_lo, v_hi = max(0, int(v0 - ra)), min(H, int(v0 + ra) + 1)
    whole = 2.0 * rb_u + 4.0 >= W  # else only the columns within rb_u of u0 (wrapped), each once
    u_lo = 0 if whole else int(np.floor(u0 - rb_u)) - 1
    n_u = W if whole else int(np.ceil(u0 + rb_u)) + 2 - u_lo
    for v in range(v_lo, v_hi):
        dv = (v - v0) / ra
        for iu in range(n_u):
            u = (u_lo + iu) % W
            du = (u - u0 + W / 2.0) % W - W / 2.0
            r2 = dv * dv + (du / rb_u) ** 2
            if r2 < 1.0:
                tgt = partner[labels[v, u]]
                if tgt >= 0:
                    logits[v, u, tgt] += np.float32(push * lat[v] / lat_max * (1.0 - r2) ** 0.5)


@nb.njit(cache=True)
def _vertical_runs(labels):
    """Run lengths along columns: ``up[v, u]`` / ``down[v, u]`` = pixels from (v, u) up / down to the end of
    its run of equal labels, itself included (rows scanned in order, vectorised along the row)."""
    H, W = labels.shape
    up = np.ones((H, W), np.int32)
    down = np.ones((H, W), np.int32)
    for v in range(1, H):
        for u in range(W):
            if labels[v, u] == labels[v - 1, u]:
                up[v, u] = up[v - 1, u] + 1
    for v in range(H - 2, -1, -1):
        for u in range(W):
            if labels[v, u] == labels[v + 1, u]:
                down[v, u] = down[v + 1, u] + 1
    return up, down


@nb.njit(cache=True, parallel=True)
def _erode_boundaries(logits, labels, top, field, radius, radius_f, push):
    """Near a label boundary, add ``push * max(0, 1 - (d - 0.5) / radius_f) * exp(0.4 field)`` to the logit
    of the neighbour's expected class (``d - 0.5``: the pixel centre's distance to the boundary, pixels;
    ``radius`` = the search bound, the pixels whose centre can lie within ``radius_f``).

    The neighbour is the nearest different label within ``radius`` pixels along the row (longitude
    wraps) or the column (edge rows repeated, so a run reaching the image edge has no neighbour there);
    at equal distance the first of left, right, up, down. Found from run lengths, not by probing every
    offset."""
    H, W = labels.shape
    up, down = _vertical_runs(labels)
    for v in nb.prange(H):
        left = np.zeros(W, np.int64)  # distance to the first different label on the left (0: none)
        right = np.zeros(W, np.int64)
        row = labels[v]
        j = -1  # start of the current run, in the doubled row
        for i in range(1, 2 * W):
            a = i - W if i >= W else i
            b = a - 1 if a > 0 else W - 1
            if row[a] != row[b]:
                j = i
            if i >= W and j >= 0:
                left[i - W] = i - j + 1
        j = -1
        for i in range(2 * W - 2, -1, -1):
            a = i - W if i >= W else i
            b = a + 1 if a < W - 1 else 0
            if row[a] != row[b]:
                j = i
            if i < W and j >= 0:
                right[i] = j - i + 1
        for u in range(W):
            best = radius + 1
            nbr = -1
            if 0 < left[u] < best:
                best, nbr = left[u], labels[v, (u - left[u]) % W]
            if 0 < right[u] < best:
                best, nbr = right[u], labels[v, (u + right[u]) % W]
            d = up[v, u]
            if v - d >= 0 and d < best:
                best, nbr = d, labels[v - d, u]
            d = down[v, u]
            if v + d < H and d < best:
                best, nbr = d, labels[v + d, u]
            if nbr > 0:
                tgt = top[nbr]
                if tgt >= 0:
                    decay = max(0.0, 1.0 - (best - 0.5) / radius_f)
                    logits[v, u, tgt] += np.float32(push * decay * np.exp(np.float32(0.4) * field[v, u]))


@nb.njit(cache=True, parallel=True)
def _scale(logits, s):
    """``logits *= s`` in place (float32)."""
    H, W, C = logits.shape
    for v in nb.prange(H):
        for u in range(W):
            for k in range(C):
                logits[v, u, k] *= s


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
