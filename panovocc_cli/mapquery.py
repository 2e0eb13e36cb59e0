"""Ask a finished map in words: :class:`MapQuery` opens a map folder once and answers as often as wanted.

The maths (matching words to the map's classes, scoring voxels, clustering) is
:mod:`panovocc_cli.semantics.query`; this module opens the map (``Mapper.load``, a file read), which the
maths layer does not (tests/test_layers.py). ``panovocc query`` answers through :class:`MapQuery`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import PanovoccError
from .semantics import query as text_query
from .semantics.query import (DEFAULT_MARGIN, DEFAULT_MIN_SIMILARITY, DEFAULT_TEMPERATURE, TEXT_MODEL, TextEncoder,
                              check_query, class_distribution, find_clusters, match_classes, voxel_scores)


def open_map(map_dir: str | Path):
    """The :class:`~panovocc_cli.mapping.mapper.Mapper` of a finished map folder (``panovocc map``'s output).

    Raises
    ------
    PanovoccError
        One line naming the folder: not found, not a map run's folder, or its memory not saved yet.
    """
    from .io import mapstore
    from .io.atomic import is_output_of_kind
    from .mapping.mapper import Mapper

    map_dir = Path(map_dir)
    if not map_dir.is_dir():
        raise PanovoccError("map folder not found", map_dir)
    mapstore.read_map_config(map_dir)  # one-line error when there is no readable config.json
    if not is_output_of_kind(map_dir, "map"):
        raise PanovoccError("not a panovocc map folder (its config.json is not a map run's)", map_dir)
    if not (map_dir / mapstore.MEMORY_NAME).is_file():
        raise PanovoccError(f"no {mapstore.MEMORY_NAME} (the map run has not saved its memory yet)", map_dir)
    return Mapper.load(map_dir)


def map_segmenter_spec(map_dir: str | Path) -> str:
    """The segmenter spec a map folder was made with (its config.json's ``semantic.segmenter``; "" if none)."""
    from .io import mapstore

    sem = mapstore.read_map_config(map_dir).get("semantic") or {}
    return str(sem.get("segmenter", "")) if isinstance(sem, dict) else ""


def feature_text_encoder(map_dir: str | Path) -> TextEncoder:
    """The text encoder whose space a feature map's embeddings live in: the text side of the segmenter the
    map was made with (MiniLM for ``simulated``, CLIP's text tower for ``clip``), loaded now."""
    from .semantics.registry import build_segmenter

    return build_segmenter(map_segmenter_spec(map_dir)).text_encoder()


def needs_features(map_dir: str | Path, what: str):
    """The one-line refusal of a feature route on a map made without ``--features``."""
    return PanovoccError(f"{what} needs the map's feature memory, which this map lacks: make it with "
                         "`panovocc map SEQ OUT --features` (or use --by classes)", Path(map_dir) / "config.json")


@dataclass
class QueryAnswer:
    """One question's answer.

    result : dict, JSON-able (see :meth:`MapQuery.ask`); scores : (n,) float64 score of each occupied voxel
    of :attr:`MapQuery.export`; mask : (n,) bool, the matching voxels; clusters : list of Cluster, all of them,
    best first (``result`` lists the best ``top``)
    """

    result: dict
    scores: np.ndarray
    mask: np.ndarray
    clusters: list


class MapQuery:
    """A finished map opened once and asked in words as often as wanted::

        q = MapQuery("work/demo/map")
        q.ask("a place to sleep", top=3)   # loads the text model (once), then answers
        q.ask("somewhere to sit")          # only embeds the text and scores the voxels

    The map folder is opened (``Mapper.load``) and exported (labels, GSC) here, once; the text model is
    loaded at the first question. ``panovocc query`` answers through this object.

    Parameters
    ----------
    map_dir : str or Path, a ``panovocc map`` output folder (config.json, memory.npz); never written
    encoder : callable ``() -> TextEncoder``, called once, at the first question (None:
        :func:`~panovocc_cli.semantics.query.minilm_encoder`, the packaged MiniLM, for the class route;
        :func:`feature_text_encoder`, the map's own, for the feature route)
    by : ``auto`` (features when the map has them, else classes), ``features`` or ``classes``: how a text
        reaches the voxels. Features: each occupied voxel's cosine to the text's projected embedding
        (:mod:`panovocc_cli.semantics.features`); classes: the text matched to the map's vocabulary

    Attributes
    ----------
    vocab : list of C class names; export : MapExport of the map (occupied voxels, labels, channels);
    voxel_size : float, metres; open_seconds : float, seconds spent opening and exporting the map

    Memory: the export (the occupied voxels' keys, labels and channels, as ``panovocc query`` held them) and,
    from the first question on, their class distribution ``(n, C) float64`` (8 C bytes per occupied voxel), or
    by features their unit features ``(n, D) float64`` (8 D bytes per occupied voxel).

    Raises
    ------
    PanovoccError
        The folder is not a finished map (:func:`open_map`), or it has no semantic evidence.
    """

    def __init__(self, map_dir: str | Path, encoder: Callable[[], TextEncoder] | None = None, by: str = "auto"):
        t0 = time.perf_counter()
        self.map_dir = map_dir
        if by not in ("auto", "features", "classes"):
            raise PanovoccError(f"--by must be auto, features or classes, got {by!r}")
        mapper = open_map(map_dir)
        try:
            self.feature_dim = int(mapper.config.feature_dim)
            if by == "features" and not self.feature_dim:
                raise needs_features(map_dir, "a query by features")
            self.by = "features" if by == "auto" and self.feature_dim else ("classes" if by == "auto" else by)
            self.vocab = list(mapper.config.vocab)
            if not self.vocab:
                raise PanovoccError("the map has no semantic evidence (mapped with --segmenter none): it cannot be "
                                    "queried by words", Path(map_dir) / "config.json")
            self.export = mapper.export()
            self.voxel_size = float(mapper.config.geometry.voxel_size)
        finally:
            mapper.close()
        self._load_encoder = encoder
        self._encode: TextEncoder | None = None
        self._p: np.ndarray | None = None  # (n, C) float64 class distribution of the occupied voxels, once
        self._u: np.ndarray | None = None  # (n, D) float64 unit features of the occupied voxels, once
        self._P: np.ndarray | None = None  # (F, D) the map's projection, once
        self.open_seconds = time.perf_counter() - t0

    @property
    def encode(self) -> TextEncoder:
        """The text model, loaded at the first use."""
        if self._encode is None:
            if self._load_encoder is not None:
                self._encode = self._load_encoder()
            elif self.by == "features":
                self._encode = feature_text_encoder(self.map_dir)
            else:
                self._encode = text_query.minilm_encoder()  # looked up when loaded
        return self._encode

    def answer(self, text: str, top: int = 5, *, min_voxels: int = 3, min_similarity: float = DEFAULT_MIN_SIMILARITY,
               margin: float = DEFAULT_MARGIN, temperature: float = DEFAULT_TEMPERATURE) -> QueryAnswer:
        """:meth:`ask`'s answer with the per-voxel scores, the matching voxels and every cluster (for pictures)."""
        t0 = time.perf_counter()
        text = check_query(text)  # before the text model is loaded
        if self.by == "features":
            return self._answer_features(text, top, t0, min_voxels=min_voxels, min_similarity=min_similarity,
                                         margin=margin)
        match = match_classes(text, self.vocab, self.encode, min_similarity=min_similarity, margin=margin,
                              temperature=temperature)
        ex, vocab = self.export, self.vocab
        labels = ex.labels
        if self._p is None:
            self._p = class_distribution(ex.channels["E"], ex.channels["S"], labels)
        scores = voxel_scores(self._p, match.weights)
        mask = np.isin(labels, match.matched) if len(match.matched) else np.zeros(len(labels), bool)
        clusters = find_clusters(ex.occupied_keys, mask, scores, labels, vocab, self.voxel_size, min_voxels,
                                 ex.origin_index)
        best = np.flatnonzero(mask)[np.argsort(-scores[mask], kind="stable")][:20]
        centres = ex.centres(best)
        result = {"query": match.query, "map": str(self.map_dir), "text_model": TEXT_MODEL, "vocabulary": vocab,
                  "match": match.to_json(), "voxels": int(mask.sum()), "clusters_total": len(clusters),
                  "clusters": [c.to_json() for c in clusters[:top]],
                  "best_voxels": [{"centre_m": [round(float(x), 4) for x in c], "score": round(float(s), 4),
                                   "class": vocab[int(lab)]} for c, s, lab in zip(centres, scores[best], labels[best])],
                  "seconds": round(time.perf_counter() - t0, 3)}
        return QueryAnswer(result, scores, mask, clusters)

    def _answer_features(self, text: str, top: int, t0: float, *, min_voxels: int, min_similarity: float,
                         margin: float) -> QueryAnswer:
        """The feature route: cosine of every occupied voxel's fused feature with the text's projected
        embedding; voxels within ``margin`` of the best voxel's cosine and above ``min_similarity`` match."""
        from .semantics.features import feature_scores, project, projection, unit_rows

        ex, vocab = self.export, self.vocab
        e = np.asarray(self.encode([text]), np.float64)[0]
        if self._u is None:  # once: the map's projection and its voxels' unit features
            self._P = projection(len(e), self.feature_dim)
            self._u = unit_rows(ex.channels["Z"])
        scores = feature_scores(self._u, project(e, self._P), unit=True)
        best_score = float(scores.max()) if len(scores) else -1.0
        thr = max(float(min_similarity), best_score - float(margin))
        mask = scores >= thr
        labels = ex.labels if ex.labels is not None else np.full(len(scores), -1)
        clusters = find_clusters(ex.occupied_keys, mask, scores, labels, vocab, self.voxel_size, min_voxels,
                                 ex.origin_index)
        best = np.flatnonzero(mask)[np.argsort(-scores[mask], kind="stable")][:20]
        centres = ex.centres(best)
        has = scores > -1.0
        match = {"query": text, "by": "features", "best_cosine": round(best_score, 4), "threshold": round(thr, 4),
                 "voxels_with_features": int(has.sum()), "matched": []}
        result = {"query": text, "map": str(self.map_dir), "text_model": map_segmenter_spec(self.map_dir) + " text",
                  "vocabulary": vocab, "by": "features", "match": match, "voxels": int(mask.sum()),
                  "clusters_total": len(clusters), "clusters": [c.to_json() for c in clusters[:top]],
                  "best_voxels": [{"centre_m": [round(float(x), 4) for x in c], "score": round(float(s), 4),
                                   "class": vocab[int(lab)] if lab >= 0 else None}
                                  for c, s, lab in zip(centres, scores[best], labels[best])],
                  "seconds": round(time.perf_counter() - t0, 3)}
        return QueryAnswer(result, scores, mask, clusters)

    def ask(self, text: str, top: int = 5, *, min_voxels: int = 3, min_similarity: float = DEFAULT_MIN_SIMILARITY,
            margin: float = DEFAULT_MARGIN, temperature: float = DEFAULT_TEMPERATURE) -> dict:
        """Answer one question in words.

        Parameters
        ----------
        text : str, non-empty; top : int, clusters listed (best first); min_voxels : int, smallest cluster;
        min_similarity, margin, temperature : as :func:`match_classes`

        Returns
        -------
        dict (JSON-able), what ``panovocc query`` prints from: ``query``, ``map``, ``text_model``,
        ``vocabulary``, ``match`` (similarity per class, matched classes with weights), ``voxels`` (matching
        voxels), ``clusters_total``, ``clusters`` (the best ``top``, :meth:`Cluster.to_json`), ``best_voxels``
        (up to 20 centres in metres with their scores) and ``seconds`` (this question's time; the first
        question's includes loading the text model)
        """
        return self.answer(text, top, min_voxels=min_voxels, min_similarity=min_similarity, margin=margin,
                           temperature=temperature).result
