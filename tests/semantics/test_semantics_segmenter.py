"""Vocabulary parsing and the segmenter factory."""

import numpy as np
import pytest

from panovocc_cli.classes import DEFAULT_VOCAB, EVAL8
from panovocc_cli.errors import PanovoccError
from panovocc_cli.semantics.precomputed import PrecomputedSegmenter, write_precomputed
from panovocc_cli.classes import parse_class_set, parse_vocab
from panovocc_cli.semantics.registry import build_segmenter
from panovocc_cli.semantics.simulated import SimulatedSegmenter


def test_default_vocab_is_eval8_plus_open4():
    assert parse_vocab() == list(DEFAULT_VOCAB)
    assert parse_vocab("default") == list(DEFAULT_VOCAB)
    assert parse_vocab("eval8+open4") == list(DEFAULT_VOCAB)
    assert parse_vocab("eval12") == list(DEFAULT_VOCAB)
    assert parse_vocab("eval8") == list(EVAL8)


def test_vocab_lists_are_canonical_lowercase_and_deduplicated():
    assert parse_vocab(" Chair, SOFA ,chair,lamp,lighting,tv-screen") == ["chair", "sofa", "lighting", "tv"]
    assert parse_vocab("eval8,wall,pillow") == list(EVAL8) + ["pillow"]
    assert parse_vocab(["Rug", "rug", "floor"]) == ["rug", "floor"]


@pytest.mark.parametrize("spec", ["", " , ", "+", []])
def test_empty_vocab_is_an_error(spec):
    with pytest.raises(PanovoccError, match="empty vocabulary"):
        parse_vocab(spec)


@pytest.mark.parametrize("spec", ["chair,empty", "unlabeled"])
def test_reserved_names_are_rejected(spec):
    with pytest.raises(PanovoccError, match="reserved"):
        parse_vocab(spec)


def test_too_many_classes():
    with pytest.raises(PanovoccError, match="at most 253"):
        parse_vocab([f"c{i}" for i in range(254)])


def test_make_segmenter_specs(tmp_path):
    assert isinstance(build_segmenter("simulated"), SimulatedSegmenter)
    write_precomputed(tmp_path, 0, np.zeros((2, 4, 2), np.float32), ["wall", "floor"])
    seg = build_segmenter(f"precomputed:{tmp_path}")
    assert isinstance(seg, PrecomputedSegmenter) and seg.spec == f"precomputed:{tmp_path}"


@pytest.mark.parametrize("spec,msg", [("oracle", "unknown segmenter"), ("precomputed:", "needs a folder"),
                                      ("precomputed:/nonexistent/dir", "not found")])
def test_bad_segmenter_specs(spec, msg):
    with pytest.raises(PanovoccError, match=msg):
        build_segmenter(spec)


def test_negative_noise_is_an_error():
    with pytest.raises(PanovoccError, match="noise"):
        build_segmenter("simulated", noise=-1)


def test_simulated_needs_ground_truth():
    seg = build_segmenter("simulated")  # no label source
    with pytest.raises(PanovoccError, match="ground-truth labels"):
        seg.logits(np.zeros((4, 8, 3), np.uint8), ["wall"], frame_id=0)
    seg = build_segmenter("simulated", label_source=lambda i: (np.zeros((4, 8), np.int64), ["unlabeled"]))
    with pytest.raises(PanovoccError, match="frame id"):
        seg.logits(np.zeros((4, 8, 3), np.uint8), ["wall"])
    assert seg.logits(np.zeros((4, 8, 3), np.uint8), ["wall"], frame_id=0).shape == (4, 8, 1)


def test_simulated_confidence_specs():
    assert build_segmenter("simulated").spec == "simulated"
    seg = build_segmenter("simulated:overconfident")
    assert seg.spec == "simulated:overconfident" and seg.config.confidence == "overconfident"
    with pytest.raises(PanovoccError, match="confidence model"):
        build_segmenter("simulated:psychic")


def test_one_parser_for_vocab_and_classes():
    assert parse_class_set("eval8,pillow") == list(EVAL8) + ["pillow"]  # a set, not a class named 'eval8'
    assert parse_class_set("eval8") == parse_vocab("eval8") == list(EVAL8)
    assert parse_class_set("all", ["empty", "wall", "Lamp", "floor"]) == ["wall", "lighting", "floor"]
    assert parse_vocab("all,pillow", ["unlabeled", "wall"]) == ["wall", "pillow"]
    for bad, msg in [("eval99", "unknown class set"), ("open7,wall", "unknown class set"), ("", "empty"),
                     (" , +", "empty"), ("all", "needs data")]:
        with pytest.raises(PanovoccError, match=msg):
            parse_class_set(bad)
        with pytest.raises(PanovoccError, match=msg):
            parse_vocab(bad)
