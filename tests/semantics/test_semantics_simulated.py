"""The simulated open-vocabulary segmenter and the 2D mIoU measurement."""

import numpy as np
import pytest

from panovocc_cli.classes import DEFAULT_VOCAB, EVAL8, canonical_name
from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.erp import latitudes
from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses
from panovocc_cli.evaluation.run import SegevalConfig, run_segeval
from panovocc_cli.semantics.metrics2d import frame_scores
from panovocc_cli.semantics.registry import build_segmenter
from panovocc_cli.semantics.simulated import CONFIDENCE_MODELS, SimulatedConfig, expected_labels, simulate_logits

from semantics_helpers import CLASS_NAMES, pose, render_room
from semantics_reference import simulate_logits_numpy, smooth_fields, softmax

VOCAB = list(DEFAULT_VOCAB)
W = 256


def frames(n=6, width=W):
    out = []
    for i in range(n):
        T = pose((0.4 * np.sin(i), 0.5 * np.cos(i), 1.4 + 0.1 * i), yaw=0.9 * i)
        out.append(render_room(width, T))
    return out


@pytest.fixture(scope="module")
def room_frames():
    return frames()


def test_noise_zero_is_exact(room_frames):
    for i, (lab, _, _) in enumerate(room_frames[:2]):
        L = simulate_logits(lab, CLASS_NAMES, VOCAB, i, SimulatedConfig(noise=0))
        assert L.dtype == np.float32 and L.shape == lab.shape + (len(VOCAB),)
        pred = L.argmax(-1)
        exp = expected_labels(CLASS_NAMES, VOCAB)[lab]
        m = exp >= 0
        assert np.array_equal(pred[m], exp[m])
        # in-vocabulary classes: argmax is the class itself, with high confidence
        inv = np.isin(lab, [CLASS_NAMES.index(c) for c in ("wall", "floor", "chair", "bed", "table")])
        names = np.array(VOCAB)[pred[inv]]
        assert np.array_equal(names, np.array(CLASS_NAMES)[lab[inv]])
        assert softmax(L).max(-1)[inv].min() > 0.85


def test_out_of_vocabulary_classes_become_similar_words():
    exp = expected_labels(CLASS_NAMES, VOCAB)
    name = lambda c: VOCAB[exp[CLASS_NAMES.index(c)]]  # noqa: E731
    assert name("rug") == "floor"
    assert name("pillow") in ("bed", "sofa")
    assert name("blinds") in ("window", "curtain")
    assert name("cabinet") == "table"
    assert name("tv-screen") == "tv" and name("lamp") == "lighting"
    assert exp[0] == -1  # unlabeled


def test_default_noise_is_realistic_but_imperfect(room_frames):
    labels = {i: lab for i, (lab, _, _) in enumerate(room_frames)}
    seg = build_segmenter("simulated", seed=3, label_source=lambda i: (labels[i], CLASS_NAMES))
    total = None
    for i, (lab, _, rgb) in enumerate(room_frames):
        s = frame_scores(seg.logits(rgb, VOCAB, frame_id=i).argmax(-1), VOCAB, lab,
                         CLASS_NAMES, EVAL8)
        total = s if total is None else (total.add(s) or total)
    exact = None
    for i, (lab, _, rgb) in enumerate(room_frames):
        s = frame_scores(simulate_logits(lab, CLASS_NAMES, VOCAB, i, SimulatedConfig(noise=0)).argmax(-1), VOCAB,
                         lab, CLASS_NAMES, EVAL8)
        exact = s if exact is None else (exact.add(s) or exact)
    assert 0.25 < total.miou < 0.6
    assert total.miou < exact.miou - 0.2


def test_calibrated_confidence(room_frames):
    conf, right = [], []
    exp = expected_labels(CLASS_NAMES, VOCAB)
    for i, (lab, _, _) in enumerate(room_frames):
        P = softmax(simulate_logits(lab, CLASS_NAMES, VOCAB, i))
        m = exp[lab] >= 0
        conf.append(P.max(-1)[m])
        right.append((P.argmax(-1) == exp[lab])[m])
    c, r = np.concatenate(conf), np.concatenate(right)
    bins = np.minimum((c * 10).astype(int), 9)
    ece = sum(abs(c[bins == b].mean() - r[bins == b].mean()) * (bins == b).mean() for b in range(10)
              if (bins == b).any())
    assert ece < 0.08
    assert r[c > 0.9].mean() > r[c < 0.5].mean() + 0.3  # confident pixels are right far more often


def test_deterministic_by_seed_and_frame(room_frames):
    lab = room_frames[0][0]
    a = simulate_logits(lab, CLASS_NAMES, VOCAB, 5, SimulatedConfig(seed=7))
    b = simulate_logits(lab, CLASS_NAMES, VOCAB, 5, SimulatedConfig(seed=7))
    assert a.tobytes() == b.tobytes()
    c = simulate_logits(lab, CLASS_NAMES, VOCAB, 6, SimulatedConfig(seed=7))
    d = simulate_logits(lab, CLASS_NAMES, VOCAB, 5, SimulatedConfig(seed=8))
    # the wrong blobs move from frame to frame and seed to seed
    assert (a.argmax(-1) != c.argmax(-1)).mean() > 0.05
    assert (a.argmax(-1) != d.argmax(-1)).mean() > 0.05


def test_errors_grow_toward_the_poles():
    lab = np.full((64, 128), CLASS_NAMES.index("wall"), dtype=np.int64)
    lab[:, 40:70] = CLASS_NAMES.index("door")
    lab[:, 90:110] = CLASS_NAMES.index("chair")
    phi = np.abs(latitudes(64))
    exp = expected_labels(CLASS_NAMES, VOCAB)[lab]
    acc_eq, acc_pole = [], []
    for i in range(12):
        ok = simulate_logits(lab, CLASS_NAMES, VOCAB, i).argmax(-1) == exp
        acc_eq.append(ok[phi < np.radians(30)].mean())
        acc_pole.append(ok[phi > np.radians(60)].mean())
    assert np.mean(acc_pole) < np.mean(acc_eq) - 0.1


def test_errors_are_spatially_coherent(room_frames):
    lab = room_frames[0][0]
    exp = expected_labels(CLASS_NAMES, VOCAB)[lab]
    wrong = simulate_logits(lab, CLASS_NAMES, VOCAB, 1).argmax(-1) != exp
    # a wrong pixel's right-hand neighbour is wrong far more often than a random pixel
    p_nb = (wrong[:, :-1] & wrong[:, 1:]).sum() / max(wrong[:, :-1].sum(), 1)
    assert p_nb > 2 * wrong.mean() or p_nb > 0.8


def test_boundaries_are_eroded():
    """The eroded band is boundary_deg (2.5 degrees) wide whatever the resolution: at 256 rows that is
    3.6 pixels, at half the resolution 1.8, and the share of wrong pixels along the edge is the same."""
    lab = np.full((256, 512), CLASS_NAMES.index("wall"), dtype=np.int64)
    lab[80:176, 120:392] = CLASS_NAMES.index("table")
    cfg = SimulatedConfig(blobs=0.0, field_sigma=0.0)  # boundary term only
    top = expected_labels(CLASS_NAMES, VOCAB)

    def wrong_share(lab):
        return np.mean([simulate_logits(lab, CLASS_NAMES, VOCAB, i, cfg).argmax(-1) != top[lab] for i in range(4)],
                       axis=0)

    wrong = wrong_share(lab)
    assert wrong[79:81, 160:350].mean() > 0.3  # at the boundary (both sides)
    assert not wrong[128, 220:300].any()  # deep inside, never
    assert not wrong[70:74, 160:350].any()  # beyond the band (6+ pixels away), never
    half = wrong_share(lab[::2, ::2])  # the same scene at half the resolution: the same eroded angle
    band_full = wrong[60:100, 160:350].sum(axis=0).mean() / 256  # eroded share of a column, in image heights
    band_half = half[30:50, 80:175].sum(axis=0).mean() / 128
    assert abs(band_full - band_half) < 0.25 * band_full


def test_one_class_vocabulary_labels_everything_that_class(room_frames):
    lab = room_frames[0][0]
    L = simulate_logits(lab, CLASS_NAMES, ["chair"], 0)
    assert L.shape == lab.shape + (1,)
    assert np.isfinite(L).all() and (L.argmax(-1) == 0).all()
    # logit magnitude follows similarity: chair pixels score above wall pixels
    ch, wa = lab == CLASS_NAMES.index("chair"), lab == CLASS_NAMES.index("wall")
    assert np.median(L[ch, 0]) > np.median(L[wa, 0]) + 1.0


def test_unknown_words_get_only_low_probability(room_frames):
    lab = room_frames[0][0]
    vocab = ["spaceship", "wall", "floor", "dragon"]
    P = softmax(simulate_logits(lab, CLASS_NAMES, vocab, 0))
    wall = lab == CLASS_NAMES.index("wall")
    assert (P[wall].argmax(-1) == 1).mean() > 0.7
    assert P[..., [0, 3]][lab > 0].mean() < 0.2


def test_unlabeled_pixels_are_diffuse():
    lab = np.zeros((32, 64), dtype=np.int64)
    lab[:, :32] = CLASS_NAMES.index("wall")
    P = softmax(simulate_logits(lab, CLASS_NAMES, VOCAB, 0))
    assert P[:, 40:].max(-1).mean() < 0.5
    assert P[:, 40:].max(-1).mean() < P[:, :20].max(-1).mean()


def test_smooth_fields_unit_variance_and_periodic():
    f = smooth_fields(np.random.default_rng(0), 64, 128, 200, 6)
    assert f.shape == (64, 128, 200)
    assert abs(f.std() - 1) < 0.1
    # periodic in longitude: the two edge columns are as close as any two adjacent columns
    assert np.abs(f[:, 0] - f[:, -1]).mean() < 2 * np.abs(f[:, 1:] - f[:, :-1]).mean()


def test_bad_label_ids():
    with pytest.raises(PanovoccError, match="label ids"):
        simulate_logits(np.full((4, 8), 99), CLASS_NAMES, VOCAB, 0)


def test_segmenter_2d_miou_on_a_sequence(tmp_path):
    fr = frames(3, 64)
    write_meta(tmp_path, SequenceMeta(width=64, height=32, frames=3, class_names=CLASS_NAMES))
    poses = []
    for i, (lab, dep, rgb) in enumerate(fr):
        write_frame(tmp_path, i, rgb, dep, lab)
        poses.append(pose())
    write_sequence_poses(tmp_path, np.stack(poses))
    exact, _ = run_segeval(SegevalConfig(seq=str(tmp_path), noise=0, vocab=",".join(VOCAB)), progress=False)
    noisy, _ = run_segeval(SegevalConfig(seq=str(tmp_path), vocab=",".join(VOCAB)), progress=False)
    assert exact.frames == 3 and exact.scored == sum((f[0] > 0).sum() for f in fr)
    # a perfect in-vocabulary class has IoU 1 (wall: nothing outside the vocabulary maps to it here)
    assert exact.iou["ceiling"] == pytest.approx(1.0)
    assert noisy.miou < exact.miou


@pytest.mark.parametrize("cfg", [SimulatedConfig(), SimulatedConfig(noise=0), SimulatedConfig(seed=5, noise=2.0),
                                 SimulatedConfig(confidence="overconfident"), SimulatedConfig(confidence="raw")])
def test_compiled_simulator_matches_numpy_reference(room_frames, cfg):
    """The compiled simulator = the plain-numpy one (tests/semantics_reference.py) to float32 rounding:
    the fields are summed in a different order (|diff| ~1e-5 on logits of magnitude ~10) and the
    ellipse weights in float64 instead of float32; the argmax is identical."""
    vocab = VOCAB + ["pillow", "rug"]
    for i, (lab, _, _) in enumerate(room_frames[:3]):
        a = simulate_logits(lab, CLASS_NAMES, vocab, i, cfg)
        b = simulate_logits_numpy(lab, CLASS_NAMES, vocab, i, cfg)
        assert a.dtype == np.float32 and a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-4)
        assert np.array_equal(a.argmax(-1), b.argmax(-1))


def test_confidence_model_is_seeded_not_fitted(room_frames):
    """The frame temperature comes from the seed alone: the same logits before scaling give the same
    temperature whatever the labels; overconfident = sharper than calibrated, on the same errors."""
    lab = room_frames[0][0]
    cal = softmax(simulate_logits(lab, CLASS_NAMES, VOCAB, 0, SimulatedConfig(seed=2)))
    over = softmax(simulate_logits(lab, CLASS_NAMES, VOCAB, 0, SimulatedConfig(seed=2, confidence="overconfident")))
    assert np.array_equal(cal.argmax(-1), over.argmax(-1))  # same errors, only the temperature differs
    assert over.max(-1).mean() > cal.max(-1).mean() + 0.05
    raw = simulate_logits(lab, CLASS_NAMES, VOCAB, 0, SimulatedConfig(seed=2, confidence="raw"))
    scaled = simulate_logits(lab, CLASS_NAMES, VOCAB, 0, SimulatedConfig(seed=2))
    ratio = raw[np.abs(raw) > 1] / scaled[np.abs(raw) > 1]
    assert np.ptp(ratio) < 1e-3 and 0.5 < ratio.mean() < 3  # one temperature for the whole frame
    assert set(CONFIDENCE_MODELS) >= {"calibrated", "overconfident"}
    with pytest.raises(PanovoccError, match="confidence model"):
        simulate_logits(lab, CLASS_NAMES, VOCAB, 0, SimulatedConfig(confidence="psychic"))


def test_segeval_class_errors(tmp_path):
    fr = frames(2, 64)
    write_meta(tmp_path, SequenceMeta(width=64, height=32, frames=2, class_names=CLASS_NAMES))
    for i, (lab, dep, rgb) in enumerate(fr):
        write_frame(tmp_path, i, rgb, dep, lab)
    write_sequence_poses(tmp_path, np.stack([pose(), pose()]))
    with pytest.raises(PanovoccError, match="none of the classes"):
        run_segeval(SegevalConfig(seq=str(tmp_path), classes="foo"), progress=False)
    with pytest.raises(PanovoccError, match="unknown class set"):
        run_segeval(SegevalConfig(seq=str(tmp_path), classes="eval99"), progress=False)
    res, _ = run_segeval(SegevalConfig(seq=str(tmp_path), classes="all", noise=0), progress=False)
    assert set(res.classes) == {canonical_name(c) for c in CLASS_NAMES[1:]} and np.isfinite(res.miou)


def test_simulated_segmenter_at_a_pixel_stride():
    """Given the image at a pixel stride (the map's semantic stride), the simulator answers for those
    pixels: the same as simulating the strided labels; a size no stride explains is refused."""
    from panovocc_cli.errors import PanovoccError
    from panovocc_cli.semantics.simulated import SimulatedSegmenter

    lab = np.random.default_rng(0).integers(0, len(CLASS_NAMES), (32, 64))
    seg = SimulatedSegmenter(lambda i: (lab, CLASS_NAMES))
    out = seg.logits(np.zeros((16, 32, 3), np.uint8), VOCAB, frame_id=2)
    np.testing.assert_array_equal(out, simulate_logits(lab[::2, ::2], CLASS_NAMES, VOCAB, 2, seg.config))
    with pytest.raises(PanovoccError, match="differ"):
        seg.logits(np.zeros((15, 32, 3), np.uint8), VOCAB, frame_id=2)
