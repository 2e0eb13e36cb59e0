"""The semantic observation a map keeps of a segmenter's output, and the integer semantic delta made from it."""

from types import SimpleNamespace

import numpy as np
import pytest
from semantics_reference import measurement, softmax

from panovocc_cli.errors import PanovoccError
from panovocc_cli.mapping.contributors import D_STEPS, S_STEPS, distribution_steps, quantize_semantic_delta
from panovocc_cli.semantics.observation import Q_LEVELS, SemanticObservation, observe


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


def test_the_sums_read_each_pixel_as_measurement_does():
    """The evidence kernels' per-pixel confidence and shares (evidence._pixel_measurement, made where they are
    summed) equal measurement()'s arrays bit for bit, for every pair of levels a uint8 holds."""
    from panovocc_cli.semantics.evidence import _pixel_measurement

    q1, q2 = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    obs = SimpleNamespace(q=np.stack([q1, q2], -1).astype(np.uint8))
    conf, share = measurement(obs)
    got = np.array([_pixel_measurement(np.uint8(a), np.uint8(b)) for a, b in zip(q1.ravel(), q2.ravel())], np.float32)
    want = np.concatenate([conf.reshape(-1, 1), share.reshape(-1, 2)], 1)
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))


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


def test_class_evidence_kernel_equals_the_numpy_steps():
    """quantize_semantic_delta's class evidence, computed a row at a time (``_weighted_steps``), equals
    ``s * distribution_steps(E / S)`` of the numpy formulation on every row: random distributions, ties of the
    remainders (uniform rows over 3, 5, 7 and 12 classes, halves), one-hot rows, rows without weight or without
    evidence, tiny and large weights, and E that does not sum to S (rounding of the float sums)."""
    from panovocc_cli.mapping.contributors import _weighted_steps

    rng = np.random.default_rng(7)
    for C in (1, 3, 7, 12, 33):
        n = 500
        S = rng.uniform(0, 6, n)
        E = rng.dirichlet(np.full(C, 0.5), n) * S[:, None]
        E[:40] = S[:40, None] / C  # uniform rows: every remainder the same
        E[40:60] = 0.0
        E[40:60, rng.integers(0, C, 20)] = S[40:60]  # one-hot
        E[60:80] *= 1 + rng.normal(0, 1e-9, (20, C)) ** 2  # sums a little off S
        E[80:90] = 0.0  # weight but no class evidence
        S[90:100] = rng.uniform(0, 1 / (2 * S_STEPS), 10)  # below half a step: no evidence
        S[100:110] = rng.uniform(1e3, 1e4, 10)
        E[100:110] = rng.dirichlet(np.ones(C), 10) * S[100:110, None]
        if C % 2 == 1 and C > 1:
            E[110:120] = 0.0
            E[110:120, :2] = S[110:120, None] / 2  # halves
        s = np.rint(S * S_STEPS).astype(np.int64)
        has = s > 0
        D = np.zeros((n, C))
        D[has] = E[has] / S[has, None]
        want = s[:, None] * distribution_steps(D)
        got = np.empty((n, C), np.int64)
        _weighted_steps(np.ascontiguousarray(E), S, s, np.float64(D_STEPS), got)
        np.testing.assert_array_equal(got, want, err_msg=f"C={C}")


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
