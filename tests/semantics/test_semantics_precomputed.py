"""precomputed:DIR — round trips and every validation error."""

import json

import numpy as np
import pytest
from semantics_reference import softmax

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.images import write_png
from panovocc_cli.io.npz import write_npz
from panovocc_cli.semantics.precomputed import (MISSING_LOGPROB, PrecomputedSegmenter, write_precomputed,
                                                write_precomputed_labels)

H, W = 8, 16
FILE_VOCAB = ["wall", "floor", "lamp", "pillow"]
RGB = np.zeros((H, W, 3), np.uint8)


def random_logits(seed=0, c=len(FILE_VOCAB)):
    return np.random.default_rng(seed).normal(0, 3, (H, W, c)).astype(np.float32)


def test_logits_round_trip_and_vocab_mapping(tmp_path):
    L = random_logits()
    write_precomputed(tmp_path, 3, L, FILE_VOCAB, dtype=np.float32)
    assert json.loads((tmp_path / "vocab.json").read_text()) == ["wall", "floor", "lighting", "pillow"]
    seg = PrecomputedSegmenter(tmp_path)
    # same vocabulary: identical probabilities
    out = seg.logits(RGB, ["wall", "floor", "lighting", "pillow"], frame_id=3)
    assert out.shape == (H, W, 4) and out.dtype == np.float32
    np.testing.assert_allclose(softmax(out), softmax(L), atol=1e-5)
    # other order, alias, a missing word: matched by canonical name, missing gets ~1e-6
    out = seg.logits(RGB, ["lighting", "wall", "chair"], frame_id=3)
    np.testing.assert_allclose(out[..., 2], MISSING_LOGPROB, rtol=1e-6)
    lp = np.log(softmax(L))
    expect = softmax(np.concatenate([lp[..., [2, 0]], np.full((H, W, 1), MISSING_LOGPROB)], -1))
    np.testing.assert_allclose(softmax(out), expect, atol=1e-5)
    assert np.array_equal(out[..., :2].argmax(-1), L[..., [2, 0]].argmax(-1))


def test_float16_and_probs(tmp_path):
    L = random_logits(1)
    write_precomputed(tmp_path, 0, L, FILE_VOCAB)  # float16 by default
    write_precomputed(tmp_path, 1, softmax(L), FILE_VOCAB, kind="probs", dtype=np.float32)
    seg = PrecomputedSegmenter(tmp_path)
    a = softmax(seg.logits(RGB, FILE_VOCAB, frame_id=0))
    b = softmax(seg.logits(RGB, FILE_VOCAB, frame_id=1))
    np.testing.assert_allclose(a, softmax(L), atol=5e-3)
    np.testing.assert_allclose(b, softmax(L), atol=1e-4)
    assert np.array_equal(a.argmax(-1), L.argmax(-1))


def test_label_png_with_confidence(tmp_path):
    lab = np.random.default_rng(2).integers(0, 4, (H, W))
    lab[0, 0] = 255  # no prediction
    conf = np.full((H, W), 0.6)
    write_precomputed_labels(tmp_path, 0, lab, FILE_VOCAB, conf)
    write_precomputed_labels(tmp_path, 1, np.zeros((H, W), int), FILE_VOCAB)
    seg = PrecomputedSegmenter(tmp_path)
    P = softmax(seg.logits(RGB, FILE_VOCAB, frame_id=0))
    m = lab != 255
    assert np.array_equal(P.argmax(-1)[m], lab[m])
    np.testing.assert_allclose(P.max(-1)[m], 0.6, atol=3e-3)
    np.testing.assert_allclose(P[0, 0], 0.25, atol=1e-5)
    P1 = softmax(seg.logits(RGB, FILE_VOCAB, frame_id=1))
    np.testing.assert_allclose(P1[..., 0], 0.9, atol=1e-5)  # default confidence


def test_npz_wins_over_png(tmp_path):
    L = random_logits(3)
    write_precomputed(tmp_path, 0, L, FILE_VOCAB, dtype=np.float32)
    write_precomputed_labels(tmp_path, 0, np.zeros((H, W), int), FILE_VOCAB)
    P = softmax(PrecomputedSegmenter(tmp_path).logits(RGB, FILE_VOCAB, frame_id=0))
    assert np.array_equal(P.argmax(-1), L.argmax(-1))


def test_writer_refuses_another_vocab(tmp_path):
    write_precomputed(tmp_path, 0, random_logits(), FILE_VOCAB)
    with pytest.raises(PanovoccError, match="vocab.json already"):
        write_precomputed(tmp_path, 1, random_logits(), ["a", "b", "c", "d"])


def _setup(tmp_path, arrays=None, vocab=FILE_VOCAB):
    if vocab is not None:
        (tmp_path / "vocab.json").write_text(json.dumps(vocab))
    if arrays is not None:
        write_npz(tmp_path / "000000.npz", arrays)
    return tmp_path


@pytest.mark.parametrize("vocab_text,msg", [(None, "vocab.json: file not found"), ("[", "invalid JSON"),
                                            ("[]", "non-empty JSON list"), ('{"a": 1}', "non-empty JSON list"),
                                            ('["wall", "Wall"]', "repeat")])
def test_bad_vocab_json(tmp_path, vocab_text, msg):
    if vocab_text is not None:
        (tmp_path / "vocab.json").write_text(vocab_text)
    with pytest.raises(PanovoccError, match=msg):
        PrecomputedSegmenter(tmp_path)


def test_missing_folder(tmp_path):
    with pytest.raises(PanovoccError, match="folder not found"):
        PrecomputedSegmenter(tmp_path / "nope")


@pytest.mark.parametrize("arrays,msg", [
    ({"scores": np.zeros((H, W, 4), np.float32)}, "expected an array 'logits' or 'probs'"),
    ({"logits": np.zeros((H, W), np.float32)}, r"must be \(H, W, C\)"),
    ({"logits": np.zeros((H, W + 2, 4), np.float32)}, "the frame is 16x8"),
    ({"logits": np.zeros((H, W, 3), np.float32)}, "has 3 classes, vocab.json has 4"),
    ({"logits": np.full((H, W, 4), np.nan, np.float32)}, "NaN"),
    ({"logits": np.zeros((H, W, 4), np.int32)}, "must be float16/float32"),
    ({"probs": np.full((H, W, 4), 0.5, np.float32)}, "sum to 1"),
])
def test_bad_npz(tmp_path, arrays, msg):
    seg = PrecomputedSegmenter(_setup(tmp_path, arrays))
    with pytest.raises(PanovoccError, match=msg) as e:
        seg.logits(RGB, FILE_VOCAB, frame_id=0)
    assert "000000.npz" in str(e.value) and "\n" not in str(e.value)


def test_missing_frame(tmp_path):
    seg = PrecomputedSegmenter(_setup(tmp_path, {"logits": np.zeros((H, W, 4), np.float32)}))
    with pytest.raises(PanovoccError, match="frame 000001 not found"):
        seg.logits(RGB, FILE_VOCAB, frame_id=1)


def test_bad_label_pngs(tmp_path):
    _setup(tmp_path)
    write_png(tmp_path / "000000.png", np.full((H, W), 7, np.uint8))
    write_png(tmp_path / "000001.png", np.zeros((H, W + 2), np.uint8))
    write_png(tmp_path / "000002.png", np.zeros((H, W), np.uint8))
    write_png(tmp_path / "000002_conf.png", np.zeros((H, W + 2), np.uint8))
    seg = PrecomputedSegmenter(tmp_path)
    with pytest.raises(PanovoccError, match="label id 7 but vocab.json has 4"):
        seg.logits(RGB, FILE_VOCAB, frame_id=0)
    with pytest.raises(PanovoccError, match="the frame is 16x8"):
        seg.logits(RGB, FILE_VOCAB, frame_id=1)
    with pytest.raises(PanovoccError, match="confidence must be"):
        seg.logits(RGB, FILE_VOCAB, frame_id=2)


def test_no_overlap_with_the_vocabulary(tmp_path):
    seg = PrecomputedSegmenter(_setup(tmp_path, {"logits": np.zeros((H, W, 4), np.float32)}))
    with pytest.raises(PanovoccError, match="none of the vocabulary words"):
        seg.logits(RGB, ["spaceship"], frame_id=0)


def test_corrupt_npz(tmp_path):
    """A file that is not a zip archive, and a zip archive that is broken, are each refused in one line."""
    _setup(tmp_path)
    (tmp_path / "000000.npz").write_bytes(b"not a zip")
    with pytest.raises(PanovoccError, match=r"not an \.npz file \(not a zip archive\); expected an \.npz holding"):
        PrecomputedSegmenter(tmp_path).logits(RGB, FILE_VOCAB, frame_id=0)
    (tmp_path / "000000.npz").write_bytes(b"PK\x03\x04 but no more of a zip")
    with pytest.raises(PanovoccError, match="cannot read"):
        PrecomputedSegmenter(tmp_path).logits(RGB, FILE_VOCAB, frame_id=0)


def test_frame_given_at_a_pixel_stride(tmp_path):
    """The map command hands a segmenter the image at its semantic stride (pixels (s i, s j)): stored
    full-size scores then give those pixels' scores; sizes that no stride explains are refused."""
    L = random_logits(4)
    write_precomputed(tmp_path, 0, L, FILE_VOCAB, dtype=np.float32)
    lab = np.random.default_rng(5).integers(0, 4, (H, W))
    write_precomputed_labels(tmp_path, 1, lab, FILE_VOCAB)
    seg = PrecomputedSegmenter(tmp_path)
    full = seg.logits(RGB, FILE_VOCAB, frame_id=0)
    half = seg.logits(RGB[::2, ::2], FILE_VOCAB, frame_id=0)
    assert half.shape == (H // 2, W // 2, 4)
    np.testing.assert_array_equal(half, full[::2, ::2])
    third = seg.logits(RGB[::3, ::3], FILE_VOCAB, frame_id=1)  # 3 x 6 of the 8 x 16 labels
    np.testing.assert_array_equal(third, seg.logits(RGB, FILE_VOCAB, frame_id=1)[::3, ::3])
    with pytest.raises(PanovoccError, match="the frame is 5x3"):
        seg.logits(np.zeros((3, 5, 3), np.uint8), FILE_VOCAB, frame_id=0)


def test_logits_stride_rule():
    from panovocc_cli.frame import logits_stride

    assert logits_stride((512, 1024), (512, 1024)) == 1
    assert logits_stride((512, 1024), (256, 512)) == 2
    assert logits_stride((10, 20), (4, 7)) == 3  # ceil(10/3), ceil(20/3)
    assert logits_stride((10, 20), (4, 8)) == 0  # no single stride gives both
    assert logits_stride((512, 1024), (0, 0)) == 0
