"""Issue 24, a vocabulary that does not cover every surface, on the feature route: ``relabel --vocab couch,bed`` by
features leaves the voxels of other words occupied-unclassed (254), counted, with the margin an option.

The text models here share a common direction, as real ones do (MiniLM's nouns lie at cosine 0.3-0.6 of each
other): an absolute cosine threshold cannot tell "this voxel is a bed" from "this voxel is more like bed than
like couch"; background words can.
"""

import zlib

import numpy as np
import pytest

from panovocc_cli.semantics import features as F
from panovocc_cli.semantics.background import DEFAULT_BACKGROUND, background_words

SYNONYMS = {"couch": "sofa", "lamp": "lighting"}  # the text model's synonyms (a near-copy of the other word)


def shared_encoder(dim=384, common=0.75):
    """A deterministic text model whose unrelated words lie at cosine about ``common ** 2`` (0.56) of each other
    (a hashed random part plus one shared direction), and whose synonyms (:data:`SYNONYMS`) at about 0.95."""
    c = np.random.default_rng(7).standard_normal(dim)
    c /= np.linalg.norm(c)

    def raw(t):
        r = np.random.default_rng(zlib.crc32(t.encode())).standard_normal(dim)
        return r / np.linalg.norm(r)

    def enc(texts):
        out = []
        for t in texts:
            r = raw(SYNONYMS[t]) + 0.3 * raw(t) if t in SYNONYMS else raw(t)
            r = r / np.linalg.norm(r)
            out.append(common * c + np.sqrt(1 - common ** 2) * r)
        out = np.stack(out)
        return (out / np.linalg.norm(out, axis=1, keepdims=True)).astype(np.float32)

    return enc


def test_background_words_leave_other_surfaces_unclassed_on_hand_made_features():
    enc = shared_encoder()
    P = F.projection(384, 64)
    truth = ["wall", "floor", "ceiling", "sofa", "bed", "rug"]
    rng = np.random.default_rng(3)
    U = F.project(enc(np.repeat(truth, 20)) + rng.normal(0, 0.002, (120, 384)), P)
    S = 64 * rng.integers(1, 40, len(U))
    Z = (S[:, None] // 64) * np.rint(127 * U).astype(np.int64)
    words = ["couch", "bed"]
    T = F.project(enc(words), P)
    # the absolute threshold alone: every voxel takes a word (walls are as like "bed" as unrelated words are)
    p0, best = F.feature_distribution(Z, T)
    assert (p0.argmax(axis=1) < 2).all() and best.min() > 0.4
    bg = ["wall", "floor", "ceiling", "sofa", "table"]
    e = enc(bg)
    fold = F.fold_targets(enc(words), e)
    np.testing.assert_array_equal(fold, [-1, -1, -1, 0, -1])  # sofa counts for couch, the rest for 254
    p, _ = F.feature_distribution(Z, T, background=F.project(e, P), fold=fold)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    got = p.argmax(axis=1).reshape(len(truth), 20)
    assert (got[:3] == 2).all()  # wall, floor, ceiling: unclassed
    assert (got[3] == 0).all() and (got[4] == 1).all()  # sofa -> couch, bed -> bed
    assert (got[5] == 2).mean() < 1  # rug: no background word; the nearest asked word may take it
    # the margin is the threshold: a large one unclasses everything, a very negative one nothing
    hi, _ = F.feature_distribution(Z, T, background=F.project(e, P), fold=fold, margin=1.0)
    lo, _ = F.feature_distribution(Z, T, background=F.project(e, P), fold=fold, margin=-1.0)
    assert (hi.argmax(axis=1) == 2).all() and (lo.argmax(axis=1) < 2).all()
    # no background word counts for 254 when every one folds into an asked word
    allfold = F.fold_targets(enc(words), enc(["sofa", "couch"]))
    np.testing.assert_array_equal(allfold, [0, 0])


def test_background_word_lists():
    assert background_words("scannet200") == DEFAULT_BACKGROUND and len(DEFAULT_BACKGROUND) == 203
    assert background_words("none") == ()
    assert background_words(" wall, floor,wall ,") == ("wall", "floor")


@pytest.fixture(scope="module")
def shared_map(tmp_path_factory):
    """The furnished room at 128x64, 6 frames, mapped with a one-word vocabulary and --features, the simulated
    segmenter's text model replaced by :func:`shared_encoder`."""
    from semantics_helpers import room_feature_map

    with room_feature_map(tmp_path_factory.mktemp("featcover"), shared_encoder) as (m, _):
        yield m


def _truth_of_voxels(path):
    """(labels of the occupied voxels of the grid at ``path``, the name of the furnished room's box holding each
    voxel's centre, or 'structure')."""
    from semantics_helpers import BOXES

    from panovocc_cli.io.grid import read_grid

    g = read_grid(path)
    ijk = np.argwhere((g.labels >= 1) & (g.labels <= 254))
    pts = np.asarray(g.origin) + ijk * g.voxel_size
    name = np.full(len(pts), "structure", object)
    for n, lo, hi in BOXES:  # later boxes win (the pillow on the bed)
        inside = np.all((pts >= np.array(lo) - 0.05) & (pts <= np.array(hi) + 0.05), axis=1)
        name[inside] = n
    return g.labels[tuple(ijk.T)], name, g


def test_relabel_couch_bed_by_features_leaves_walls_unclassed_and_counts_them(shared_map, tmp_path, capsys):
    from cli_helpers import run_cli
    from semantics_helpers import CLASS_NAMES

    from panovocc_cli.classes import canonical_name
    from panovocc_cli.cli.query_cmds import RelabelConfig, run_relabel

    enc = shared_encoder()
    names = [canonical_name(n) for n in CLASS_NAMES[1:]]
    # the reference: the room's own words (background words that are its words count for them: few unclassed)
    full = run_relabel(RelabelConfig(shared_map, tmp_path / "all.npz", vocab=",".join(names)), encode=enc)
    assert full["unclassed"] < 0.01 * full["occupied"]
    ref, _, gf = _truth_of_voxels(tmp_path / "all.npz")
    ref = np.array(gf.class_names, object)[np.minimum(ref, len(gf.class_names) - 1)]
    res = run_relabel(RelabelConfig(shared_map, tmp_path / "cb.npz", vocab="couch,bed"), encode=enc)
    lab, name, g = _truth_of_voxels(tmp_path / "cb.npz")
    assert g.class_names == ["empty", "couch", "bed"]
    assert int((lab == 254).sum()) == res["unclassed"] and res["unclassed"] + sum(res["classed"].values()) == \
        res["occupied"] == len(lab)
    structure = np.isin(ref, ["wall", "floor", "ceiling"])
    assert structure.sum() > 0.5 * len(lab)
    assert (lab[structure] == 254).mean() > 0.99  # walls, floor, ceiling: no word
    assert res["unclassed"] > 0.8 * res["occupied"]
    assert (lab[ref == "bed"] == 2).mean() > 0.6 and (lab[ref == "sofa"] == 1).mean() > 0.6
    # background words of the room's other surfaces only (this text model's 200 ScanNet names are random words,
    # whose best one is closer to a noisy voxel than a real model's would be): the words keep their voxels
    others = ",".join(n for n in names if n not in ("bed", "sofa")) + ",sofa"  # sofa counts for couch
    own = run_relabel(RelabelConfig(shared_map, tmp_path / "own.npz", vocab="couch,bed", background=others),
                      encode=enc)
    assert [s for s, _ in own["sources"]["couch"]] == ["features", "sofa"]
    lab, _, _ = _truth_of_voxels(tmp_path / "own.npz")
    assert (lab[ref == "bed"] == 2).mean() > 0.8 and (lab[ref == "sofa"] == 1).mean() > 0.8  # bed: some to pillow
    assert (lab[structure] == 254).mean() > 0.99 and (lab[ref == "pillow"] == 254).mean() > 0.8
    assert (ref[lab == 2] == "bed").mean() > 0.8 and (ref[lab == 1] == "sofa").mean() > 0.8
    # without background words the absolute threshold gives nearly every voxel a word (the failure this fixes)
    old = run_relabel(RelabelConfig(shared_map, tmp_path / "old.npz", vocab="couch,bed", background="none"),
                      encode=enc)
    assert old["unclassed"] < 0.05 * old["occupied"]
    # the margin is the option: higher leaves more unclassed, and the count follows the grid
    strict = run_relabel(RelabelConfig(shared_map, tmp_path / "strict.npz", vocab="couch,bed", background=others,
                                       feature_margin=0.1), encode=enc)
    assert strict["unclassed"] > own["unclassed"]
    assert int((_truth_of_voxels(tmp_path / "strict.npz")[0] == 254).sum()) == strict["unclassed"]
    # the command reports the count, and the background synonyms that count for each word
    import panovocc_cli.cli.query_cmds as qc

    mp = pytest.MonkeyPatch()
    real = qc.run_relabel
    mp.setattr(qc, "run_relabel", lambda cfg: real(cfg, encode=enc))
    try:
        code, text, err = run_cli(capsys, ["relabel", shared_map, tmp_path / "cli.npz", "--vocab", "couch,bed",
                                           "--background", others, "--feature-margin", "0.05"])
    finally:
        mp.undo()
    assert code == 0, err
    lines = text.strip().splitlines()
    assert lines[0].startswith("couch") and "sofa" in lines[0]
    lab, _, _ = _truth_of_voxels(tmp_path / "cli.npz")
    assert f"{int((lab == 254).sum())} without a class" in lines[-1]
