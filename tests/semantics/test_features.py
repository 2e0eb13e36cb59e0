"""The feature memory (issue 24): a channel Z of fused, projected, quantised embeddings per voxel.

Exact under revise, remove, resume (delta log round trip); the simulated segmenter's embedding mode; the
projection; scores and relabel evidence on hand-made features.
"""

import numpy as np
import pytest
from semantics_helpers import write_labelled_room

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.mapping import Mapper
from panovocc_cli.mapping.config import SemanticParams
from panovocc_cli.mapping.pipeline import MapConfig, load_config, run_map, sequence_frames
from panovocc_cli.semantics import features as F

W = 64
N = 4
D = 16


def fake_encoder(dim=256):
    """A deterministic stand-in text model (no torch): each text's hashed unit vector, so that equal words
    embed equally and different words nearly orthogonally."""
    import zlib

    def enc(texts):
        out = np.stack([np.random.default_rng(zlib.crc32(t.encode())).standard_normal(dim) for t in texts])
        return (out / np.linalg.norm(out, axis=1, keepdims=True)).astype(np.float32)

    return enc


@pytest.fixture(scope="module")
def fmapped(tmp_path_factory):
    """The labelled room mapped with --features (D = 16); the simulated segmenter's text model replaced by
    :func:`fake_encoder` (its embedding space), so that no torch is loaded."""
    from panovocc_cli.semantics.simulated import SimulatedSegmenter

    root = tmp_path_factory.mktemp("featseq")
    seq = write_labelled_room(root / "room", W, N)
    mp = pytest.MonkeyPatch()
    mp.setattr(SimulatedSegmenter, "text_encoder", lambda self: fake_encoder())
    out = root / "m"
    run_map(MapConfig(seq=str(seq), out=str(out), checkpoint_every=2,
                      semantic=SemanticParams(features=True, feature_dim=D)), progress=False)
    cfg = load_config(out)
    yield out, cfg, sequence_frames(cfg, Sequence(seq))
    mp.undo()


def _same(a, b):
    x, y = a.memory.to_arrays(), b.memory.to_arrays()
    assert sorted(x) == sorted(y)
    for k in x:
        np.testing.assert_array_equal(x[k], y[k], err_msg=k)


def _moved(T, seed):
    rng = np.random.default_rng(seed)
    out = T.copy()
    out[:3, 3] += rng.normal(0, 0.15, 3)
    return out


def test_feature_channel_is_saved_and_exact_under_revise_remove_and_reload(fmapped, tmp_path):
    out, cfg, frames = fmapped
    mc = cfg.mapper_config()
    assert mc.feature_dim == D
    with np.load(out / "memory.npz") as z:
        assert "Z" in z["channel_names"].tolist()
    loaded = Mapper.load(out)  # the delta log and memory.npz of the run
    direct = Mapper(mc)
    for i in range(N):
        direct.integrate(frames(i))
    _same(loaded, direct)
    keys, ch = direct.memory.nonzero()
    Z, S = np.asarray(ch["Z"]), np.asarray(ch["S"]).reshape(-1)
    assert Z.shape[1] == D and np.any(Z != 0)
    assert not np.any(Z[S == 0])  # kept only where semantic evidence fell
    assert np.all(np.abs(Z) <= 127 * S[:, None] // 64)  # s times a mean of int8 values
    # revise: a wrong pose, then the true one again -> bit for bit the direct memory (no segmenter call)
    m = Mapper(mc, frame_source=frames.read)
    for i in range(N):
        f = frames(i)
        if i == 1:
            f.T_world_cam = _moved(f.T_world_cam, 3)
        m.integrate(f)
    with pytest.raises(AssertionError):
        _same(m, direct)
    assert m.revise(1, frames.read(1).T_world_cam)
    _same(m, direct)
    # remove = never added
    m.remove(2)
    without = Mapper(mc)
    for i in (0, 1, 3):
        without.integrate(frames(i))
    _same(m, without)
    # saved and loaded through the delta log: the kept observation holds the int8 features
    folder = m.save(tmp_path / "r")
    back = Mapper.load(folder, frame_source=frames.read)
    _same(back, without)
    obs = back._rpu.store.get(0).observation
    assert obs.features.dtype == np.int8 and obs.features.shape[2] == D
    back.integrate(frames(2))
    _same(back, direct)


def test_a_feature_map_refuses_frames_without_features(fmapped):
    _, cfg, frames = fmapped
    m = Mapper(cfg.mapper_config())
    f = frames(0)
    f.features = None
    with pytest.raises(PanovoccError, match="carries none"):
        m.integrate(f)


def test_features_need_a_segmenter_that_gives_them(tmp_path):
    seq = write_labelled_room(tmp_path / "room", 32, 1)
    with pytest.raises(PanovoccError, match="--features needs"):
        run_map(MapConfig(seq=str(seq), out=str(tmp_path / "m"), semantic=SemanticParams(segmenter="none",
                                                                                        features=True)),
                progress=False)
    assert not (tmp_path / "m").exists()


def test_projection_is_fixed_orthonormal_and_keeps_cosines():
    P = F.projection(384, 64)
    np.testing.assert_array_equal(P, F.projection(384, 64))
    np.testing.assert_allclose(P.T @ P, np.eye(64), atol=1e-12)
    assert not np.array_equal(P, F.projection(384, 64, seed=F.FEATURE_SEED + 1))
    rng = np.random.default_rng(0)
    x = rng.standard_normal((200, 384))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    a, b = x[:100] + x[100:], x[:100]  # pairs with cosine about 0.7
    cos = np.sum(a * b, 1) / np.linalg.norm(a, axis=1)
    pa, pb = F.project(a, P), F.project(b, P)
    err = np.abs(np.sum(pa * pb, 1) - cos)
    assert err.mean() < 0.1  # the random subspace's distortion, about 1 / sqrt(64)
    q = F.quantize_features(a.reshape(10, 10, 384), P)
    assert q.dtype == np.int8 and q.shape == (10, 10, 64)
    np.testing.assert_allclose(np.linalg.norm(q.astype(float), axis=2), 127, rtol=0.05)
    with pytest.raises(PanovoccError, match="dimension 383"):
        F.project(np.ones(383), P)
    up = F.projection(24, 32)  # more dimensions than the source: an isometry
    np.testing.assert_allclose(up @ up.T, np.eye(24), atol=1e-12)


def test_scores_and_evidence_on_hand_made_features():
    """Voxels whose stored features are known words' embeddings: a query for a word ranks its voxels first,
    relabelling puts each voxel on its word, and a voxel whose feature matches no word is unclassed."""
    enc = fake_encoder(32)
    P = F.projection(32, 8)
    words = ["bed", "sofa", "floor"]
    T = F.project(enc(words), P)
    rng = np.random.default_rng(1)
    truth = np.repeat(np.arange(3), 5)
    S = 64 * rng.integers(1, 50, len(truth) + 2)
    U = np.concatenate([T[truth], np.zeros((1, 8)), F.project(rng.standard_normal(8), np.eye(8))[None]])
    Z = (S[:, None] // 64) * np.rint(127 * U).astype(np.int64)
    s = F.feature_scores(Z, F.project(enc(["sofa"])[0], P))
    assert s[-2] == -1.0  # no feature
    assert set(np.argsort(-s)[:5]) == set(np.flatnonzero(truth == 1))
    from panovocc_cli.mapping.contributors import distribution_evidence

    p, best = F.feature_distribution(Z, T, min_similarity=0.9)
    E = distribution_evidence(p, S)
    assert E.shape == (len(S), 4) and E.dtype == np.int64
    np.testing.assert_array_equal(E.sum(axis=1), S)
    np.testing.assert_array_equal(np.argmax(E[:15], axis=1), truth)
    assert E[-2, 3] == S[-2] and E[-1, 3] == S[-1]  # no feature; a feature far from every word
    assert best[-2] == -1.0 and best[-1] < 0.9


def test_simulated_embedding_mode_is_seeded_and_near_the_true_class():
    from panovocc_cli.semantics.simulated import SimulatedConfig, SimulatedSegmenter

    names = ["unlabeled", "wall", "floor", "bed"]
    lab = np.zeros((16, 32), np.int64)
    lab[:6], lab[6:11], lab[11:] = 1, 3, 2
    enc = fake_encoder(24)

    def seg(noise):
        s = SimulatedSegmenter(lambda i: (lab, names), SimulatedConfig(noise=noise, seed=3))
        s.text_encoder = lambda: enc
        return s

    exact = seg(0.0).features(None, frame_id=0)
    emb = enc(["wall", "floor", "bed"])
    true = emb[lab.reshape(-1) - 1]
    np.testing.assert_allclose(np.sum(F.unit_rows(exact.reshape(-1, 24)) * true, 1), 1.0, atol=0.02)
    a, b = seg(1.0).features(None, frame_id=5), seg(1.0).features(None, frame_id=5)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, seg(1.0).features(None, frame_id=6))
    cos = np.sum(F.unit_rows(a.reshape(-1, 24)) * true, 1)
    assert 0.5 < np.median(cos) < 0.999  # noisy but mostly the true class


# --- asking a feature map --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def qmap(tmp_path_factory):
    """The furnished room at 128x64, 6 frames, mapped with a one-word vocabulary and --features: the words
    of the room are known to the map only through its features. The text model is :func:`fake_encoder`."""
    from semantics_helpers import room_feature_map

    with room_feature_map(tmp_path_factory.mktemp("featq"), fake_encoder) as m:
        yield m


def _in_box(pts, name, slack=0.2):
    from semantics_helpers import BOXES

    lo, hi = next((np.array(a), np.array(b)) for n, a, b in BOXES if n == name)
    return np.all((pts >= lo - slack) & (pts <= hi + slack), axis=1)


def test_query_by_features_finds_a_word_the_map_was_never_given(qmap, tmp_path):
    from panovocc_cli.cli.query_cmds import QueryConfig, format_query, run_query
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.mapquery import MapQuery

    out, _ = qmap
    q = MapQuery(out, encoder=fake_encoder)
    assert q.by == "features" and q.vocab == ["object"]
    a = q.answer("bed", top=3)
    assert a.result["by"] == "features" and a.result["voxels"] > 20
    pts = q.export.centres(np.flatnonzero(a.mask))
    assert _in_box(pts, "bed").mean() > 0.8
    box = a.result["clusters"][0]
    assert _in_box(np.array([box["centroid_m"]]), "bed")[0]
    # the same question again: the same answer (the map and the encoder kept)
    b = q.answer("bed", top=3)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert "by features" in format_query(a.result)
    # --out: a grid of the matches, and a heat picture
    [res] = run_query(QueryConfig(out, ["sofa"], out=tmp_path / "sofa.npz"), encode=fake_encoder())
    g = read_grid(tmp_path / "sofa.npz")
    assert g.class_names == ["empty", "sofa"] and int((g.labels == 1).sum()) == res["voxels"] > 0
    run_query(QueryConfig(out, ["sofa"], out=tmp_path / "heat.png"), encode=fake_encoder())
    assert (tmp_path / "heat.png").read_bytes()[:4] == b"\x89PNG"


def test_relabel_by_features_to_words_the_map_never_saw_and_eval(qmap, tmp_path, capsys):
    from cli_helpers import run_cli
    from semantics_helpers import CLASS_NAMES

    from panovocc_cli.cli.query_cmds import RelabelConfig, run_relabel
    from panovocc_cli.io.grid import read_grid

    from panovocc_cli.classes import canonical_name

    out, seq = qmap
    names = [canonical_name(n) for n in CLASS_NAMES[1:]]
    res = run_relabel(RelabelConfig(out, tmp_path / "all.npz", vocab=",".join(names)), encode=fake_encoder())
    assert res["by_features"] and res["vocab"] == names
    g = read_grid(tmp_path / "all.npz")
    assert g.class_names == ["empty"] + names
    assert res["classed"]["wall"] > res["classed"]["bed"] > 20 and res["unclassed"] < 0.1 * res["occupied"]
    # a vocabulary that covers few surfaces: the rest is occupied-unclassed (254), counted
    few = run_relabel(RelabelConfig(out, tmp_path / "few.npz", vocab="bed,zebra"), encode=fake_encoder())
    assert few["classed"]["bed"] > 20 and few["classed"]["zebra"] < 0.1 * few["classed"]["bed"]
    assert few["unclassed"] > 0.6 * few["occupied"]
    labels = read_grid(tmp_path / "few.npz").labels
    assert int((labels == 254).sum()) == few["unclassed"]
    # the threshold is the option: 1.0 leaves nearly nothing classed
    none = run_relabel(RelabelConfig(out, tmp_path / "none.npz", vocab="bed", min_feature_similarity=1.0),
                       encode=fake_encoder())
    assert none["classed"]["bed"] < 0.05 * none["occupied"]
    # merges of stored classes mean nothing to the feature route
    with pytest.raises(PanovoccError, match="merges stored classes"):
        run_relabel(RelabelConfig(out, tmp_path / "m.npz", vocab="seat=object"), encode=fake_encoder())
    # panovocc eval scores the relabelled grid
    code, text, err = run_cli(capsys, ["eval", tmp_path / "all.npz", tmp_path / "all.npz", "--classes", "all"])
    assert code == 0, err and "mIoU" in text


def test_feature_routes_on_a_map_without_features_name_the_option(tmp_path, capsys):
    from cli_helpers import run_cli

    seq = write_labelled_room(tmp_path / "room", 64, 2)
    run_map(MapConfig(seq=str(seq), out=str(tmp_path / "m"), checkpoint_every=0), progress=False)
    for argv in (["query", tmp_path / "m", "bed", "--by", "features"],
                 ["relabel", tmp_path / "m", tmp_path / "n.npz", "--vocab", "bed", "--by", "features"]):
        code, out, err = run_cli(capsys, argv)
        assert code == 2 and "--features" in err and len(err.strip().splitlines()) == 1, (argv, err)
    assert not (tmp_path / "n.npz").exists()


def test_resume_of_a_feature_map_gives_the_bytes_of_an_uninterrupted_run(fmapped, tmp_path):
    """``map`` killed after frame 3 (checkpoint at 2) and resumed: memory.npz and the grid equal the run that
    was never interrupted (the feature channel included)."""
    from panovocc_cli.semantics.simulated import SimulatedSegmenter

    out, cfg, _ = fmapped
    part = tmp_path / "part"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SimulatedSegmenter, "text_encoder", lambda self: fake_encoder())
        st = run_map(MapConfig(seq=cfg.seq, out=str(part), checkpoint_every=2,
                               semantic=SemanticParams(features=True, feature_dim=D)), progress=False, stop_after=3)
        assert st["stopped_at"] == 3
        run_map(resume_out=part, progress=False)
    for name in ("memory.npz", "prediction.npz"):
        assert (part / name).read_bytes() == (out / name).read_bytes(), name
