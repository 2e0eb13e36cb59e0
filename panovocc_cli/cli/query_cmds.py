"""``query`` (a finished map asked in words) and ``relabel`` (its grid under a new vocabulary).

The maths is :mod:`panovocc_cli.semantics.query`; ``run_query`` asks :class:`panovocc_cli.mapquery.MapQuery` (the map opened and
exported once, the text model loaded once, for any number of texts) and writes ``--out``; ``run_relabel`` opens
the map folder (``Mapper.load``: memory.npz, config.json) and writes the new grid. Both are usable from Python.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import typer

from ..config import option, validate_config
from ..errors import PanovoccError, printable
from ..semantics.features import (DEFAULT_FEATURE_MARGIN_254, DEFAULT_FEATURE_MIN_SIMILARITY,
                                  DEFAULT_FEATURE_TEMPERATURE, DEFAULT_FOLD_SIMILARITY)
from ..semantics.query import (DEFAULT_MARGIN, DEFAULT_MIN_SIMILARITY, DEFAULT_RELABEL_SIMILARITY,
                               DEFAULT_TEMPERATURE)
from ._app import app
from .options import OptionValues, config_command

QUERY_OUTPUTS = (".json", ".ply", ".png", ".npz")
BY = ("auto", "features", "classes")
#: relabel: the column of the evidence of the stored classes that no new word takes (exported as 254).
UNMATCHED = "(no new word)"
#: Colours of query pictures and point clouds: voxels that do not match, and the score ramp's ends.
OTHER_COLOR = (170, 170, 170)
MATCH_LOW, MATCH_HIGH = (255, 210, 60), (200, 20, 20)


@dataclass
class QueryConfig:
    """Options of ``panovocc query``."""

    map_dir: Path = option(argument=True, metavar="OUT", help="Map folder written by panovocc map (config.json, "
                           "memory.npz).")
    texts: list[str] = option(argument=True, metavar="TEXT", help="What to look for, in words, e.g. 'a place "
                              "to sleep'; several texts are answered in order, the map and the text model loaded "
                              "once.")
    top: int = option(5, min=1, max=1000, help="Number of clusters listed (best first).")
    out: Path | None = option(None, help="Also write the answer (one TEXT only): .json (classes, clusters, best voxels), .ply "
                              "(occupied voxels, matches coloured by score), .png (top view with boxes, matches "
                              "coloured by score) or .npz (a CONVENTIONS grid: matching voxels 1, other occupied "
                              "254, free 0, unobserved 255).")
    by: str = option("auto", choices=BY, help="How the text reaches the voxels: features (cosine to each voxel's "
                     "fused feature; maps made with --features), classes (matched to the map's vocabulary), auto "
                     "(features when the map has them).")
    min_voxels: int = option(3, min=1, help="Smallest cluster reported, in voxels.")
    min_similarity: float = option(DEFAULT_MIN_SIMILARITY, min=-1.0, max=1.0, help="Text cosine a class needs "
                                   "to match the query.")
    margin: float = option(DEFAULT_MARGIN, min=0.0, max=2.0, help="Matched classes lie within this cosine of the "
                           "best class.")
    temperature: float = option(DEFAULT_TEMPERATURE, min=1e-3, max=10.0, help="Softmax temperature (cosine units) "
                                "of the matched classes' weights.")
    overwrite: bool = option(False, help="Replace an existing --out file (never an input).")


@dataclass
class RelabelConfig:
    """Options of ``panovocc relabel``."""

    map_dir: Path = option(argument=True, metavar="OUT", help="Map folder written by panovocc map.")
    out_npz: Path = option(argument=True, metavar="NEW.npz", help="Grid to write (CONVENTIONS.md grid .npz).")
    vocab: str = option(help="New vocabulary: words, comma-separated; NAME=old1+old2 merges stored classes "
                        "explicitly (e.g. 'bed,seating=chair+sofa,floor,wall').")
    min_similarity: float = option(DEFAULT_RELABEL_SIMILARITY, min=-1.0, max=1.0, help="Text cosine a stored class "
                                   "needs to its most similar new word to go to it; voxels won by classes that go "
                                   "to no word get no class (254).")
    by: str = option("auto", choices=BY, help="features: label each occupied voxel by its fused feature's cosine to "
                     "the words (any words; maps made with --features); classes: through the stored class evidence; "
                     "auto: features when the map has them.")
    min_feature_similarity: float = option(DEFAULT_FEATURE_MIN_SIMILARITY, min=-1.0, max=1.0,
                                           help="By features: the cosine a voxel's best word needs; below it the "
                                                "voxel is occupied without a class (254).")
    feature_temperature: float = option(DEFAULT_FEATURE_TEMPERATURE, min=1e-3, max=10.0,
                                        help="By features: softmax temperature (cosine units) of a voxel's "
                                             "distribution over the words.")
    background: str = option("scannet200", help="By features: the words a voxel may be instead of the asked ones, "
                             "which leave it occupied without a class (254): scannet200 (ScanNet200's 200 class names "
                             "and LERF's canonical phrases), none, or comma-separated words.")
    fold_similarity: float = option(DEFAULT_FOLD_SIMILARITY, min=-1.0, max=1.0, help="By features: text cosine a "
                                    "background word needs to its most similar asked word to count for it (a "
                                    "synonym: 'sofa chair' for 'couch').")
    feature_margin: float = option(DEFAULT_FEATURE_MARGIN_254, min=-2.0, max=2.0, help="By features: the cosine "
                                   "an asked word needs over the best background word that counts for no asked word "
                                   "(negative: the word keeps a voxel unless such a word is closer by more than "
                                   "that; larger: more voxels unclassed).")
    overwrite: bool = option(False, help="Replace an existing NEW.npz (never an input).")


def run_query(cfg: QueryConfig, encode=None) -> list[dict]:
    """Answer each of ``cfg.texts`` on the map in ``cfg.map_dir`` (opened and exported once, the text model
    loaded once: :class:`panovocc_cli.mapquery.MapQuery`); write ``cfg.out`` when given (one text only).

    Parameters
    ----------
    cfg : QueryConfig (``texts``: a list of texts, or one str)
    encode : TextEncoder or None (the packaged MiniLM, :func:`semantics.query.minilm_encoder`)

    Returns
    -------
    list of dict, one per text in order, each :meth:`MapQuery.ask`'s answer (JSON-able): ``query``,
    ``text_model``, ``match``, ``voxels``, ``clusters`` (the best ``top``), ``best_voxels``, ``seconds``

    Raises
    ------
    PanovoccError
        Before the map or the text model is loaded: an empty or non-UTF-8 text, ``out`` with several
        texts or a suffix other than .json/.ply/.png, an existing ``out`` without ``overwrite``.
    """
    from ..io.runconfig import check_file_output
    from ..mapquery import MapQuery
    from ..semantics.query import check_query

    cfg = validate_config(cfg)
    texts = [cfg.texts] if isinstance(cfg.texts, str) else list(cfg.texts)
    if not texts:
        raise PanovoccError("no TEXT given; expected what to look for, in words, e.g. 'a place to sleep'")
    for k, text in enumerate(texts, 1):
        check_query(text, "the query" if len(texts) == 1 else f"TEXT {k} of {len(texts)}")
    if cfg.out is not None:
        if len(texts) > 1:
            raise PanovoccError(f"--out writes the answer to one TEXT; got {len(texts)} texts (ask them one by one "
                                f"with --out, or print all answers with --json)", cfg.out)
        if Path(cfg.out).suffix.lower() not in QUERY_OUTPUTS:
            raise PanovoccError(f"--out must end in {', '.join(QUERY_OUTPUTS)}", cfg.out)
        check_file_output(cfg.out, "query", cfg.overwrite, inputs=[cfg.map_dir])
    q = MapQuery(cfg.map_dir, encoder=None if encode is None else (lambda: encode), by=cfg.by)
    answers = [q.answer(t, cfg.top, min_voxels=cfg.min_voxels, min_similarity=cfg.min_similarity,
                        margin=cfg.margin, temperature=cfg.temperature) for t in texts]
    if cfg.out is not None:
        a = answers[0]
        _write_query_output(cfg, a.result, q.export, q.voxel_size, a.scores, a.mask, a.clusters[:cfg.top])
    return [a.result for a in answers]


def _score_colors(s):
    import numpy as np

    t = np.clip(np.asarray(s, np.float64), 0.0, 1.0)[:, None]
    return np.rint(np.array(MATCH_LOW) * (1 - t) + np.array(MATCH_HIGH) * t).astype(np.uint8)


def _write_query_output(cfg: QueryConfig, result: dict, ex, h: float, scores, mask, clusters) -> None:
    import numpy as np

    from ..io.atomic import output_file, write_text
    from ..io.runconfig import config_path_beside, write_run_config

    out = Path(cfg.out)
    suffix = out.suffix.lower()
    pts = ex.centres()
    cols = np.tile(np.array(OTHER_COLOR, np.uint8), (len(pts), 1))
    cols[mask] = _score_colors(scores[mask])
    with output_file(out):
        if suffix == ".json":  # without the timing: the same question gives the same bytes
            write_text(out, json.dumps({k: v for k, v in result.items() if k != "seconds"}, indent=2) + "\n")
        elif suffix == ".ply":
            from ..io.ply import write_ply_points

            write_ply_points(out, pts, cols)
        elif suffix == ".npz":
            from ..grid import OCCUPIED_UNKNOWN_CLASS, Grid
            from ..io.grid import write_grid

            g = ex.grid
            labels = g.labels.copy()
            labels[(labels >= 1) & (labels <= 253)] = OCCUPIED_UNKNOWN_CLASS
            idx = np.rint((pts[mask] - np.asarray(g.origin, np.float64)) / g.voxel_size).astype(np.int64)  # origin:
            #                                                                         the first voxel's centre
            labels[tuple(idx.T)] = 1
            write_grid(out, Grid(labels, g.origin, g.voxel_size, ["empty", result["query"]]))
        else:
            from ..io.figures import write_png

            write_png(_top_view(pts, cols, mask, clusters, result, h), out)
    write_run_config(config_path_beside(out), cfg)


def _top_view(pts, cols, mask, clusters, result, h):
    """A matplotlib figure: the occupied voxels seen from above, one pixel per voxel column (grey; a column
    holding a match takes the colour of its best-scoring match), the listed clusters' boxes numbered."""
    import numpy as np
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    ij = np.floor(pts[:, :2] / h).astype(np.int64)
    i0 = ij.min(axis=0)
    ij -= i0
    nx, ny = ij.max(axis=0) + 1
    img = np.full((ny, nx, 3), 255, np.uint8)
    img[ij[:, 1], ij[:, 0]] = OTHER_COLOR
    order = np.flatnonzero(mask)
    order = order[np.argsort(cols[order, 1].astype(np.int64) * -1, kind="stable")]  # best score (least green) last
    img[ij[order, 1], ij[order, 0]] = cols[order]
    x0, y0 = i0 * h
    width_in = 9.0
    fig = Figure(figsize=(width_in, max(3.0, width_in * ny / nx + 1.0)))
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(img, origin="lower", extent=(x0, x0 + nx * h, y0, y0 + ny * h), interpolation="nearest")
    for k, c in enumerate(result["clusters"], 1):
        (bx0, by0, _), (bx1, by1, _) = c["bbox_min_m"], c["bbox_max_m"]
        ax.add_patch(Rectangle((bx0, by0), bx1 - bx0, by1 - by0, fill=False, edgecolor="black", linewidth=1.5))
        ax.text(bx0, by1, f" {k}", va="bottom", ha="left", fontsize=11, weight="bold")
    matched = ", ".join(f"{m['class']} {m['similarity']:.2f}" for m in result["match"]["matched"]) or "no class"
    ax.set_title(printable(f"\"{result['query']}\" -> {matched} (top view, boxes: best clusters)"), fontsize=11)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    return fig


def run_relabel(cfg: RelabelConfig, encode=None) -> dict:
    """Write the map's grid under a new vocabulary its stored evidence supports.

    The stored evidence ``E (n, C_old)`` becomes ``E @ M`` (:func:`semantics.query.relabel_matrix`), plus one
    column holding the evidence of the stored classes no new word takes (below ``min_similarity``), and the
    map's own export (occupancy rule, GSC, nearest-evidence transfer) labels the occupied voxels with the
    new words; a voxel that column wins is occupied without a class (254). Returns a summary: ``vocab``,
    ``sources`` per new word, ``classed`` voxels per new word, ``unclassed`` occupied voxels without one.

    By features (``cfg.by``; a map made with ``--features``): the evidence is written from each voxel's fused
    feature instead (:func:`semantics.features.feature_distribution`: a softmax over its cosines to the words and
    to the ``background`` words, those that are no synonym of a word (``fold_similarity``) scoring for the extra
    column, plus ``feature_margin``; a voxel whose best cosine is below ``min_feature_similarity`` all on the
    extra column), so any words are reached; then the same export. ``by_features`` in the summary says which
    route was taken.
    """
    import dataclasses

    import numpy as np

    from ..classes import canonical_name
    from ..io.runconfig import check_file_output
    from ..mapping.export import export_memory
    from ..mapquery import open_map
    from ..semantics.query import minilm_encoder, parse_relabel_vocab, relabel_matrix

    cfg = validate_config(cfg)
    if Path(cfg.out_npz).suffix.lower() != ".npz":
        raise PanovoccError("output must be a .npz grid", cfg.out_npz)
    config_path = check_file_output(cfg.out_npz, "grid", cfg.overwrite, inputs=[cfg.map_dir])
    new = parse_relabel_vocab(cfg.vocab)
    mapper = open_map(cfg.map_dir)
    try:
        stored = list(mapper.config.vocab)
        if not stored:
            raise PanovoccError("the map has no semantic evidence (mapped with --segmenter none)",
                                Path(cfg.map_dir) / "config.json")
        by_features = cfg.by == "features" or (cfg.by == "auto" and bool(mapper.config.feature_dim))
        words = [w for w, _ in new]
        if by_features:
            ex, sources = _relabel_by_features(cfg, mapper, new, encode)
        else:
            needs_text = any(not olds and w not in {canonical_name(s) for s in stored} for w, olds in new)
            if needs_text and encode is None:
                encode = minilm_encoder()
            M, sources = relabel_matrix(stored, new, encode, cfg.min_similarity)
            # the stored classes no new word takes keep their evidence in one more column, so the voxels that
            # evidence wins come out without a class (254), not with the best of the new words
            M = np.concatenate([M, (~M.any(axis=1))[:, None].astype(np.int64)], axis=1)
            keys, ch = mapper.memory.nonzero()
            ch = dict(ch)
            ch["E"] = np.asarray(ch["E"], np.int64) @ M
            mcfg = dataclasses.replace(mapper.config, vocab=words + [UNMATCHED])
            ex = export_memory(keys, ch, mcfg.geometry.voxel_size, mcfg.occupancy, mcfg.vocab, mcfg,
                               origin_index=mcfg.origin_index())
    finally:
        mapper.close()
    return _write_relabelled(cfg, ex, words, sources, config_path, by_features)


def _relabel_by_features(cfg: RelabelConfig, mapper, new, encode):
    """run_relabel's feature route: (the export under the new words + the unmatched column, sources)."""
    import dataclasses

    import numpy as np

    from ..classes import canonical_name
    from ..mapping.contributors import distribution_evidence
    from ..mapping.export import export_memory
    from ..mapquery import feature_text_encoder, needs_features
    from ..semantics.background import background_words
    from ..semantics.features import feature_distribution, fold_targets, project, projection
    from ..semantics.query import _words

    if not mapper.config.feature_dim:
        raise needs_features(cfg.map_dir, "relabel --by features")
    merged = [w for w, olds in new if olds]
    if merged:
        raise PanovoccError(f"{merged[0]!r}: NAME=old1+old2 merges stored classes, which relabelling by features does "
                            "not use; give the words alone (or use --by classes)")
    if encode is None:
        encode = feature_text_encoder(cfg.map_dir)
    words = [w for w, _ in new]
    bg = list(background_words(cfg.background))
    e = np.asarray(encode([_words(w) for w in words] + bg), np.float64)
    fold = fold_targets(e[:len(words)], e[len(words):], cfg.fold_similarity)
    P = projection(e.shape[1], mapper.config.feature_dim)
    T, B = project(e[:len(words)], P), project(e[len(words):], P)
    keys, ch = mapper.memory.nonzero()
    ch = dict(ch)
    p, _ = feature_distribution(ch["Z"], T, temperature=cfg.feature_temperature,
                                min_similarity=cfg.min_feature_similarity, background=B, fold=fold,
                                margin=cfg.feature_margin)
    ch["E"] = distribution_evidence(p, ch["S"])
    mcfg = dataclasses.replace(mapper.config, vocab=words + [UNMATCHED])
    ex = export_memory(keys, ch, mcfg.geometry.voxel_size, mcfg.occupancy, mcfg.vocab, mcfg,
                       origin_index=mcfg.origin_index())
    sources = {w: [("features", 1.0)] for w in words}
    for k, (b, j) in enumerate(zip(bg, fold)):  # the background words that count for an asked word (bar itself)
        if j >= 0 and canonical_name(b) != words[j]:
            sources[words[j]].append((b, round(float(e[len(words) + k] @ e[j]), 4)))
    return ex, sources


def _write_relabelled(cfg: RelabelConfig, ex, words, sources, config_path, by_features: bool) -> dict:
    """Write run_relabel's grid (the unmatched column's voxels as 254) and return its summary."""
    import numpy as np

    from ..grid import OCCUPIED_UNKNOWN_CLASS, Grid
    from ..io.atomic import output_file
    from ..io.grid import write_grid
    from ..io.runconfig import write_run_config

    labels = ex.grid.labels.copy()
    labels[labels == len(words) + 1] = OCCUPIED_UNKNOWN_CLASS
    grid = Grid(labels, ex.grid.origin, ex.grid.voxel_size, list(ex.grid.class_names)[:-1])
    with output_file(cfg.out_npz):
        write_grid(cfg.out_npz, grid)
    write_run_config(config_path, cfg)
    lab = ex.labels if ex.labels is not None else np.full(len(ex.occupied_keys), -1)
    counts = np.bincount(lab[lab >= 0], minlength=len(words) + 1)
    return {"vocab": words, "sources": {w: [[s, c] for s, c in v] for w, v in sources.items()},
            "classed": {w: int(n) for w, n in zip(words, counts)}, "unclassed": int(len(lab) - counts[:-1].sum()),
            "occupied": int(len(ex.occupied_keys)), "by_features": by_features}


def format_query(res: dict) -> str:
    """The query's one-screen summary."""
    m = res["match"]
    lines = [f"query: \"{res['query']}\" on {res['map']} (text model {res['text_model']})"]
    if res.get("by") == "features":
        lines.append(f"by features: best voxel cosine {m['best_cosine']:.2f}, matching from {m['threshold']:.2f} "
                     f"({m['voxels_with_features']} voxels with features)")
        if not res["voxels"]:
            lines.append("no voxel matches (lower --min-similarity to see weaker matches)")
            return "\n".join(lines)
    elif m["matched"]:
        lines.append("matched classes: " + ", ".join(f"{x['class']} (cosine {x['similarity']:.2f}, weight "
                                                      f"{x['weight']:.2f})" for x in m["matched"]))
    else:
        sims = sorted(m["similarity"].items(), key=lambda t: -t[1])
        lines.append("no class of the map's vocabulary matches (best: " + ", ".join(
            f"{k} {v:.2f}" for k, v in sims[:3]) + "); try one of: " + ", ".join(res["vocabulary"]))
        return "\n".join(lines)
    lines.append(f"{res['voxels']} matching voxels in {res['clusters_total']} clusters; the best "
                 f"{len(res['clusters'])}:")
    lines.append(f"{'#':>3} {'voxels':>7} {'score':>6}  {'centroid (m)':<22} {'size (m)':<18} classes")
    for k, c in enumerate(res["clusters"], 1):
        cen = ", ".join(f"{x:.2f}" for x in c["centroid_m"])
        size = " x ".join(f"{x:.2f}" for x in c["size_m"])
        cls = ", ".join(f"{n} {v}" for n, v in c["classes"].items())
        lines.append(f"{k:>3} {c['voxels']:>7} {c['score_mean']:>6.2f}  {cen:<22} {size:<18} {cls}")
    return "\n".join(lines)


@config_command(app, QueryConfig, "query")
def query(o: OptionValues, as_json: bool = typer.Option(False, "--json", help="Print the answer as one JSON "
                                                                               "object (several TEXTs: a list of "
                                                                               "them, in order) instead of a "
                                                                               "summary.")) -> None:
    """Find what free-text queries name in a finished map: matched classes, voxels, clusters with boxes (one
    block per TEXT)."""
    res = run_query(QueryConfig(**o))
    typer.echo(json.dumps(res[0] if len(res) == 1 else res) if as_json else "\n\n".join(map(format_query, res)))
    if o["out"] is not None and not as_json:
        typer.echo(f"wrote {o['out']}")


@config_command(app, RelabelConfig, "relabel")
def relabel(o: OptionValues) -> None:
    """Write a finished map's grid under a new vocabulary its stored evidence supports (merges, synonyms)."""
    res = run_relabel(RelabelConfig(**o))
    for w in res["vocab"]:
        src = ", ".join(f"{s}" + ("" if c == 1.0 else f" ({c:.2f})") for s, c in res["sources"][w])
        typer.echo(f"{w:<16} <- {src:<40} {res['classed'][w]:>7} voxels")
    typer.echo(f"wrote {o['out_npz']} ({res['occupied']} occupied voxels, {res['unclassed']} without a class)")


__all__ = ["QueryConfig", "RelabelConfig", "run_query", "run_relabel", "format_query"]
