"""The semantic observation a map keeps of a segmenter's output, and the integer semantic delta made from it."""

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.mapping.semantic import D_STEPS, S_STEPS, distribution_steps, quantize_semantic_delta
from panovocc_cli.semantics.evidence import softmax
from panovocc_cli.semantics.observation import Q_LEVELS, SemanticObservation, measurement, observe


def test_observation_is_the_top_two_softmax_in_fifteenths():
    rng = np.random.default_rng(3)
    logits = (rng.normal(size=(17, 31, 12)) * 3).astype(np.float32)
    logits[0, 0] = 0.0  # a tie everywhere: the lowest indices win
    logits[1, 1, [4, 9]] = 50.0  # a tie between two classes
    obs = observe(logits)
    p = softmax(logits).astype(np.float64)
    order = np.argsort(-p, axis=2, kind="stable")[..., :2]
    np.testing.assert_array_equal(obs.classes, order)
    np.testing.assert_array_equal(obs.q, np.rint(np.take_along_axis(p, order, 2) * Q_LEVELS))
    assert obs.classes[0, 0].tolist() == [0, 1] and obs.classes[1, 1].tolist() == [4, 9]
    conf, share = measurement(obs)
    np.testing.assert_allclose(conf, obs.q[..., 0] / 15)
    np.testing.assert_allclose(share.sum(-1)[obs.q.sum(-1) > 0], 1, rtol=1e-6)


@pytest.mark.parametrize("C", [1, 2, 16, 17, 40])
def test_observation_arrays_round_trip(C):
    rng = np.random.default_rng(C)
    obs = observe(rng.normal(size=(9, 14, C)).astype(np.float32))
    back = SemanticObservation.from_arrays(obs.to_arrays())
    assert back.n_classes == C
    np.testing.assert_array_equal(back.classes, obs.classes)
    np.testing.assert_array_equal(back.q, obs.q)
    if C == 1:
        assert (obs.q[..., 0] == 15).all() and (obs.q[..., 1] == 0).all()


def test_bad_logits_and_observations_are_refused():
    with pytest.raises(PanovoccError, match="finite"):
        observe(np.full((2, 2, 3), np.nan, np.float32))
    with pytest.raises(PanovoccError, match=r"\(h, w, C\)"):
        observe(np.zeros((2, 3), np.float32))
    with pytest.raises(PanovoccError, match="255"):
        observe(np.zeros((1, 1, 300), np.float32))
    bad = SemanticObservation(np.full((2, 2, 2), 5, np.uint8), np.zeros((2, 2, 2), np.uint8), 3)
    with pytest.raises(PanovoccError, match="class indices"):
        bad.check()


def test_distribution_steps_sum_exactly_and_round_to_nearest():
    rng = np.random.default_rng(0)
    D = rng.dirichlet(np.ones(12) * 0.3, 500)
    d = distribution_steps(D)
    assert d.dtype == np.int64 and (d >= 0).all()
    assert (d.sum(1) == D_STEPS).all()
    assert np.abs(d - D * D_STEPS).max() < 1.0  # largest remainders: never a whole step off
    np.testing.assert_array_equal(distribution_steps(np.array([[0.5, 0.5, 0.0]]), 3), [[2, 1, 0]])  # ties: lower
    np.testing.assert_array_equal(distribution_steps(np.zeros((2, 4))), np.zeros((2, 4)))


def test_integer_semantic_delta_factors_and_sums():
    rng = np.random.default_rng(1)
    n, C = 200, 7
    count = rng.integers(1, 30, n)
    S = rng.uniform(0, 4, n)
    S[:5] = 1e-4  # below half a step: no class evidence
    E = rng.dirichlet(np.ones(C), n) * S[:, None]
    nrm = rng.normal(size=(n, 3)) * count[:, None] * 0.3
    rgb = rng.integers(0, 256, (n, 3)) * count[:, None]
    d = quantize_semantic_delta(np.arange(n), {"E": E, "S": S, "rgb_sum": rgb.astype(float), "normal_sum": nrm,
                                               "count": count})
    ch = d.channels
    s = np.rint(S * S_STEPS).astype(np.int64)
    np.testing.assert_array_equal(ch["S"][:, 0], D_STEPS * s)
    np.testing.assert_array_equal(ch["E"].sum(1), ch["S"][:, 0])  # E / S is a distribution
    assert (ch["E"][:5] == 0).all() and (ch["S"][:5] == 0).all() and (ch["count"][:5, 0] == count[:5]).all()
    np.testing.assert_array_equal(ch["rgb_sum"], rgb)  # whole grey levels: exact
    assert (ch["normal_sum"] % count[:, None] == 0).all()
    assert np.all(np.abs(ch["normal_sum"] / 127 - nrm) <= count[:, None] * 0.5 / 127 + 1e-12)
    assert set(d.factors) == {"E", "normal_sum", "rgb_sum"}
