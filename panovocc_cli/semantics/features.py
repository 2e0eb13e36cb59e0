"""Language-aligned features per voxel: the projection, the quantisation and the scores (pure maths, no I/O).

A map made with ``--features`` keeps, beside its class evidence, a channel ``Z`` of fused embeddings: each
measurement pixel's embedding (the segmenter's, in its own dimension F: CLIP's image space for ``clip``, the
MiniLM text space for ``simulated``) is projected to the map's D dimensions by a fixed matrix
(:func:`projection`: seeded, so the map saves only its seed and D), normalised and quantised to integers in
1/127 steps (:func:`quantize_features`, int8, kept in the frame's observation so that ``revise`` never
runs the segmenter). A voxel's per-frame delta is its weight ``s`` (the ``S`` channel's integer weight)
times the eta-weighted mean of its pixels' quantised features, rounded (:mod:`panovocc_cli.mapping.
contributors`): exact integers, so revise, remove and resume stay bit for bit, and ``Z / S`` is the voxel's
weighted mean feature in 1/(64 * 127) steps.

Asking such a map: a text is embedded by the encoder that matches the map's features, projected by the
same matrix (:func:`project`) and compared by cosine with each voxel's ``Z`` (:func:`feature_scores`).
Relabelling to any vocabulary (:func:`feature_distribution`): each voxel is classified over the asked words and
a background vocabulary (:mod:`.background`; background words that are synonyms of an asked word count for it,
:func:`fold_targets`), and the softmax of its scores over the words plus one unclassed column is written back in
the form of the class evidence ``E`` (integer steps times the voxel's weight:
:func:`panovocc_cli.mapping.contributors.distribution_evidence`), so the map's own export (GSC, nearest-evidence
transfer) labels the voxels; the voxels the unclassed column wins are occupied-unclassed (254).
"""

from __future__ import annotations

import numpy as np

from ..errors import PanovoccError

DEFAULT_FEATURE_DIM = 64
FEATURE_SEED = 24  # the projection's seed (saved in a map's config.json with D)
FEATURE_STEPS = 127  # a pixel's unit feature in 1/127 steps (int8)
MAX_FEATURE_DIM = 1024
#: relabel by features: softmax temperature over the words' cosines, and the cosine below which a voxel
#: takes no word (occupied-unclassed, 254). Chosen on homes of seeds 100-101 (docs/semantics.md).
DEFAULT_FEATURE_TEMPERATURE = 0.1
DEFAULT_FEATURE_MIN_SIMILARITY = 0.3
#: relabel by features against background words (:mod:`.background`): the text cosine a background word needs
#: to an asked word to count for it, and the cosine margin an asked word needs over the other background words.
DEFAULT_FOLD_SIMILARITY = 0.65
DEFAULT_FEATURE_MARGIN_254 = -0.03
#: query by features: voxels within this cosine of the best voxel's and above ``min_similarity`` match.
DEFAULT_FEATURE_MARGIN = 0.1


def projection(source_dim: int, dim: int, seed: int = FEATURE_SEED) -> np.ndarray:
    """The fixed projection ``(source_dim, dim)`` float64 of a map: Gaussian entries from
    ``default_rng([seed, source_dim, dim])``, made orthonormal by QR: its columns when ``dim <= source_dim``
    (cosines are kept up to the random subspace's distortion, about ``1 / sqrt(dim)``), its rows otherwise
    (an isometry: cosines kept exactly). The same arguments give the same bytes on every machine."""
    F, D = int(source_dim), int(dim)
    if F < 1 or not 1 <= D <= MAX_FEATURE_DIM:
        raise PanovoccError(f"feature projection {F} -> {D}: expected source dimension >= 1 and 1 <= D <= "
                            f"{MAX_FEATURE_DIM}")
    g = np.random.default_rng([int(seed), F, D]).standard_normal((F, D))
    q, r = np.linalg.qr(g if D <= F else g.T)
    q = q * np.where(np.diag(r) < 0, -1.0, 1.0)  # sign fixed: the factorisation's choice does not matter
    return q if D <= F else q.T


def project(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Vectors ``x (..., F)`` projected by ``P (F, D)`` and normalised to unit length (float64; a zero
    projection stays zero)."""
    x = np.asarray(x, np.float64)
    if x.shape[-1] != P.shape[0]:
        raise PanovoccError(f"features of dimension {x.shape[-1]}, the map's projection expects {P.shape[0]} (a "
                            "different segmenter or text encoder than the map was made with)")
    y = x @ P
    n = np.linalg.norm(y, axis=-1, keepdims=True)
    return np.divide(y, n, out=np.zeros_like(y), where=n > 0)


def quantize_features(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-pixel features ``x (h, w, F)`` -> the observation's ``(h, w, D)`` int8: unit projections in
    1/127 steps, ``rint(127 y)``. Computed in float32 as one (pixels, F) x (F, D) product (a frame's
    features are float32; float64 copies of them cost more than the product)."""
    x = np.asarray(x)
    if x.shape[-1] != P.shape[0]:
        return np.rint(FEATURE_STEPS * project(x, P)).astype(np.int8)  # project's one-line refusal
    y = np.ascontiguousarray(x, np.float32).reshape(-1, P.shape[0]) @ P.astype(np.float32)
    n = np.sqrt(np.einsum("ij,ij->i", y, y))[:, None]
    y = np.divide(np.float32(FEATURE_STEPS) * y, n, out=np.zeros_like(y), where=n > 0)
    return np.rint(y).astype(np.int8).reshape(x.shape[:-1] + (P.shape[1],))


def unit_rows(Z: np.ndarray) -> np.ndarray:
    """Rows of a stored ``Z (n, D)`` (any common scale) as unit vectors, float64; zero rows stay zero."""
    return project(np.asarray(Z, np.float64), np.eye(np.shape(Z)[1]))


def feature_scores(Z: np.ndarray, t: np.ndarray, *, unit: bool = False) -> np.ndarray:
    """Cosine ``(n,)`` of each voxel's fused feature (``Z (n, D)``; ``unit``: already :func:`unit_rows`, kept
    by a caller that asks many times) with the projected text ``t (D,)``; voxels without a feature (a zero
    row) score -1."""
    U = np.asarray(Z, np.float64) if unit else unit_rows(Z)
    s = U @ np.asarray(t, np.float64).reshape(-1)
    s[~U.any(axis=1)] = -1.0
    return s


def fold_targets(T: np.ndarray, B: np.ndarray, min_similarity: float = DEFAULT_FOLD_SIMILARITY) -> np.ndarray:
    """Which asked word each background word counts for.

    T : (C, D) the asked words' unit text embeddings; B : (K, D) the background words'; min_similarity : the
    text cosine a background word needs to its most similar asked word to count for it (a synonym: ``sofa``
    for ``couch``, or the word itself)

    Returns (K,) int64: the asked word's index, or -1 (the background word counts for occupied-unclassed).
    """
    B = np.asarray(B, np.float64).reshape(-1, np.shape(T)[1])
    if not len(B) or not len(T):
        return np.full(len(B), -1, np.int64)
    sim = B @ np.asarray(T, np.float64).T
    j = sim.argmax(axis=1)
    return np.where(sim[np.arange(len(B)), j] >= float(min_similarity), j, -1).astype(np.int64)


def feature_distribution(Z: np.ndarray, T: np.ndarray, *, temperature: float = DEFAULT_FEATURE_TEMPERATURE,
                         min_similarity: float = DEFAULT_FEATURE_MIN_SIMILARITY, background: np.ndarray | None = None,
                         fold: np.ndarray | None = None,
                         margin: float = DEFAULT_FEATURE_MARGIN_254) -> tuple[np.ndarray, np.ndarray]:
    """Each voxel's distribution over a new vocabulary from its stored feature.

    A voxel's score for word c is its cosine to c, or to a background word that counts for c (``fold``),
    whichever is higher; the extra column's score is its best cosine to a background word that counts for
    none, plus ``margin``. The distribution is the softmax of these C + 1 scores at ``temperature``; a voxel
    whose best word cosine is below ``min_similarity`` (or without a feature) puts all its mass on the extra
    column. Without background words the extra column takes only those voxels.

    Parameters
    ----------
    Z : (n, D) stored features (any common scale); T : (C, D) the words' projected unit text embeddings
    temperature : softmax temperature over the cosines; min_similarity : best cosine a voxel needs to take a word
    background : (K, D) the background words' projected unit text embeddings, or None
    fold : (K,) int64, :func:`fold_targets` (the word each background word counts for, -1: none)
    margin : cosine added to the best background word's score (the evidence a word needs over the background)

    Returns
    -------
    p : (n, C + 1) float64, rows sum to 1 (the class evidence of a relabelled map:
        :func:`panovocc_cli.mapping.contributors.distribution_evidence`); the last column is occupied-unclassed
    best : (n,) float64, each voxel's best word cosine (-1: no feature)
    """
    U = unit_rows(Z)
    cos = U @ np.asarray(T, np.float64).T
    has = U.any(axis=1)
    best = np.where(has, cos.max(axis=1) if cos.shape[1] else -1.0, -1.0)
    other = np.full(len(U), -np.inf)
    if background is not None and len(background):
        cb = U @ np.asarray(background, np.float64).T
        fold = np.asarray(fold, np.int64)
        for c in range(cos.shape[1]):
            mine = fold == c
            if mine.any():
                cos[:, c] = np.maximum(cos[:, c], cb[:, mine].max(axis=1))
        if (fold < 0).any():
            other = cb[:, fold < 0].max(axis=1) + float(margin)
    s = np.concatenate([cos, other[:, None]], axis=1)
    z = (s - s.max(axis=1, keepdims=True)) / float(temperature)
    p = np.exp(z)
    p /= p.sum(axis=1, keepdims=True)
    off = best < float(min_similarity)
    p[off] = 0.0
    p[off, -1] = 1.0
    return p, best
