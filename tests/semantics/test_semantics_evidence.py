"""Per-frame semantic evidence: softmax, weights, ERP normals, sparse deltas, multi-frame fusion."""

import numpy as np
import pytest

from panovocc_cli.classes import DEFAULT_VOCAB
from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.geometry.lattice import pack_keys, point_to_index, unpack_keys
from panovocc_cli.semantics.evidence import (EvidenceWeights, frame_semantic_delta, measurement_weights, softmax,
                                             w_erp, w_range)
from panovocc_cli.semantics.observation import observe
from panovocc_cli.semantics.simulated import SimulatedConfig, simulate_logits

from semantics_helpers import CLASS_NAMES, pose, render_room
from semantics_reference import erp_normals, frame_semantic_delta_numpy, semantic_frame_delta

VOCAB = list(DEFAULT_VOCAB)


def test_softmax_stable_and_normalised():
    x = np.array([[1000.0, 1000.0, -1000.0], [0.0, np.log(3.0), -np.inf]])
    p = softmax(x)
    assert p.dtype == np.float32 and np.isfinite(p).all()
    np.testing.assert_allclose(p, [[0.5, 0.5, 0.0], [0.25, 0.75, 0.0]], atol=1e-6)


def test_weights():
    np.testing.assert_allclose(w_erp([0.0, np.pi / 3, np.pi / 2]), [1.0, 0.5, 0.05])
    np.testing.assert_allclose(w_range([0.0, 4.0, 8.0]), [0.0, 0.5, 0.2])
    probs = np.array([[0.7, 0.3], [0.5, 0.5]])
    eta = measurement_weights(probs, np.array([0.0, np.pi / 3]), np.array([4.0, 4.0]), EvidenceWeights())
    np.testing.assert_allclose(eta, [0.35, 0.125], rtol=1e-6)


def test_erp_normals_of_a_box_room():
    lab, depth, _ = render_room(128, pose(yaw=0.3))
    T = pose(yaw=0.3)
    rays = ray_directions(128)
    pts = rays * depth[..., None]
    n = erp_normals(pts, depth > 0)
    ok = np.linalg.norm(n, axis=-1) > 0
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.linalg.norm(n[ok], axis=-1), 1.0, atol=1e-5)
    assert (np.einsum("hwc,hwc->hw", n, pts)[ok] < 0).all()  # facing the camera
    nw = n @ T[:3, :3].T
    floor = (lab == CLASS_NAMES.index("floor")) & ok
    ceiling = (lab == CLASS_NAMES.index("ceiling")) & ok
    assert np.median(nw[floor][:, 2]) > 0.99 and np.median(nw[ceiling][:, 2]) < -0.99
    # longitude wraps: the first column's normals exist and match the room's walls
    assert ok[:, 0].mean() > 0.9


def test_erp_normals_invalid_and_shape_errors():
    pts = ray_directions(16) * 2.0
    valid = np.ones((8, 16), bool)
    valid[4, 5] = False
    n = erp_normals(pts, valid)
    assert not n[4, 5].any()
    # a sphere around the camera: normals point back along the ray
    rays = ray_directions(16)
    ok = np.linalg.norm(n, axis=-1) > 0
    np.testing.assert_allclose(np.einsum("hwc,hwc->hw", n, rays)[ok], -1.0, atol=0.05)
    with pytest.raises(PanovoccError):
        erp_normals(pts[..., :2], valid)


def brute_force_delta(pts, probs, eta, rgb, nrm, h):
    acc = {}
    for p, q, e, c, n in zip(pts, probs, eta, rgb, nrm):
        k = int(pack_keys(point_to_index(p[None], h))[0])
        a = acc.setdefault(k, [np.zeros(probs.shape[1]), 0.0, np.zeros(3), np.zeros(3), 0])
        a[0] += e * q
        a[1] += e
        a[2] += c
        a[3] += n
        a[4] += 1
    return acc


def test_semantic_frame_delta_matches_brute_force():
    rng = np.random.default_rng(0)
    m, c, h = 400, 5, 0.25
    pts = rng.uniform(-1, 1, (m, 3))
    probs = rng.dirichlet(np.ones(c), m)
    eta = rng.uniform(0, 1, m)
    rgb = rng.integers(0, 256, (m, 3)).astype(np.uint8)
    nrm = rng.normal(size=(m, 3))
    keys, ch = semantic_frame_delta(pts, probs, eta, rgb, nrm, h)
    assert keys.dtype == np.int64 and np.all(np.diff(keys) > 0)
    ref = brute_force_delta(pts, probs, eta, rgb, nrm, h)
    assert sorted(ref) == keys.tolist()
    for r, k in enumerate(keys.tolist()):
        E, S, rs, ns, cnt = ref[k]
        np.testing.assert_allclose(ch["E"][r], E)
        np.testing.assert_allclose(ch["S"][r], S)
        np.testing.assert_allclose(ch["rgb_sum"][r], rs)
        np.testing.assert_allclose(ch["normal_sum"][r], ns)
        assert ch["count"][r] == cnt
    assert ch["E"].dtype == np.float64 and ch["count"].dtype == np.int64
    np.testing.assert_allclose(ch["E"].sum(1), ch["S"])  # probabilities sum to 1


def test_semantic_frame_delta_shape_errors():
    with pytest.raises(PanovoccError, match="disagree"):
        semantic_frame_delta(np.zeros((3, 3)), np.zeros((2, 4)), np.zeros(3), np.zeros((3, 3), np.uint8),
                             np.zeros((3, 3)), 0.1)


def accumulate(deltas):
    """Sum sparse deltas keyed by voxel (what the mapper's memory does)."""
    keys = np.unique(np.concatenate([k for k, _ in deltas]))
    c = deltas[0][1]["E"].shape[1]
    E, S = np.zeros((keys.size, c)), np.zeros(keys.size)
    for k, ch in deltas:
        pos = np.searchsorted(keys, k)
        E[pos] += ch["E"]
        S[pos] += ch["S"]
    return keys, E, S


def test_wall_seen_by_many_noisy_frames_ends_up_wall():
    h, width, n = 0.16, 128, 12
    truth, noisy = [], []
    for i in range(n):
        T = pose((0.5 * np.sin(i), 0.6 * np.cos(i), 1.3 + 0.05 * i), yaw=0.6 * i)
        lab, depth, rgb = render_room(width, T)
        exact = simulate_logits(lab, CLASS_NAMES, VOCAB, i, SimulatedConfig(noise=0))
        noise = simulate_logits(lab, CLASS_NAMES, VOCAB, i, SimulatedConfig(seed=11))
        truth.append(frame_semantic_delta(depth, rgb, observe(exact), T, h))
        noisy.append(frame_semantic_delta(depth, rgb, observe(noise), T, h))
    kt, Et, St = accumulate(truth)
    kn, En, Sn = accumulate(noisy)
    assert np.array_equal(kt, kn)
    seen = np.zeros(kt.size, int)
    for k, _ in noisy:
        seen[np.searchsorted(kt, k)] += 1
    wall = VOCAB.index("wall")
    pure = (Et.argmax(1) == wall) & (Et[:, wall] > 0.8 * St)
    # away from other classes (boundary erosion is systematic, as in real segmenters): all 26
    # neighbours that hold surface are wall too
    idx = unpack_keys(kt)
    interior = pure.copy()
    for off in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T:
        nk = pack_keys(idx + off)
        pos = np.minimum(np.searchsorted(kt, nk), kt.size - 1)
        hit = kt[pos] == nk
        interior &= ~hit | pure[pos]
    is_wall = interior & (seen >= n // 2)
    assert is_wall.sum() > 50
    fused_acc = (En[is_wall].argmax(1) == wall).mean()
    # one frame alone on the same voxels
    single_acc = []
    for k, ch in noisy:
        w1 = is_wall[np.searchsorted(kt, k)]
        single_acc.append((ch["E"][w1].argmax(1) == wall).mean())
    assert fused_acc > 0.9
    assert fused_acc > np.mean(single_acc) + 0.05


def test_subtracting_a_delta_undoes_it():
    lab, depth, rgb = render_room(64)
    T = pose()
    d1 = frame_semantic_delta(depth, rgb, observe(simulate_logits(lab, CLASS_NAMES, VOCAB, 0)), T, 0.2)
    d2 = frame_semantic_delta(depth, rgb, observe(simulate_logits(lab, CLASS_NAMES, VOCAB, 1)), T, 0.2)
    k, E, S = accumulate([d1, d2])
    pos = np.searchsorted(k, d2[0])
    E[pos] -= d2[1]["E"]
    S[pos] -= d2[1]["S"]
    k1, E1, S1 = accumulate([d1])
    pos1 = np.searchsorted(k, k1)
    np.testing.assert_allclose(E[pos1], E1, atol=1e-9)
    np.testing.assert_allclose(np.delete(S, pos1), 0.0, atol=1e-9)


@pytest.mark.parametrize("width,yaw,voxel,stride,strided_logits", [(256, 0.3, 0.2, 1, False), (512, 1.1, 0.08, 1, False),
                                                                  (40, 0.5, 0.3, 1, False), (256, 0.7, 0.1, 2, False),
                                                                  (250, 0.2, 0.1, 3, True)])
def test_compiled_delta_matches_numpy_reference(width, yaw, voxel, stride, strided_logits):
    """The compiled per-frame delta = the plain-numpy chain (tests/semantics_reference.py).

    Keys, counts and colour sums are identical; the float sums agree to ~1e-6 relative (the summation order
    of a voxel whose pixels fall in several of the fixed row chunks: chunk partial sums added in chunk
    order). After quantisation the weight steps s = S / 64 agree to within one step, the normal sums
    exactly. Width 40 (20 rows) has fewer rows than chunks. With a semantic stride s the measurements are
    pixels (s i, s j) weighing s^2, observed from full-size logits taken at the stride or from logits
    made at the stride (width 250 with s = 3: 84 x 42 measurements, the last row and column partial).
    """
    from panovocc_cli.mapping.semantic import D_STEPS, quantize_semantic_delta

    T = pose(yaw=yaw)
    lab, depth, rgb = render_room(width, T)
    depth = depth.astype(np.float32)
    depth[::7, ::5] = 0.0  # holes: one-sided normals
    depth[3, :] = np.nan
    logits = simulate_logits(lab, CLASS_NAMES, VOCAB + ["pillow"], 4, SimulatedConfig(seed=3))
    if strided_logits:
        lab_s = lab[::stride, ::stride]
        logits = simulate_logits(lab_s, CLASS_NAMES, VOCAB + ["pillow"], 4, SimulatedConfig(seed=3))
    obs = observe(logits if strided_logits else logits[::stride, ::stride])
    w = EvidenceWeights(stride=stride)
    k1, c1 = frame_semantic_delta(depth, rgb, obs, T, voxel, w)
    k0, c0 = frame_semantic_delta_numpy(np.nan_to_num(depth, nan=0.0), rgb, obs, T, voxel, w)
    if stride > 1:  # the measurements are the strided pixels only
        assert c1["count"].sum() == np.count_nonzero(np.nan_to_num(depth, nan=0.0)[::stride, ::stride] > 0)
    assert np.array_equal(k0, k1)
    for name in ("rgb_sum", "count"):
        assert np.array_equal(c0[name], c1[name])
    np.testing.assert_allclose(c1["E"], c0["E"], rtol=2e-6, atol=1e-9)
    np.testing.assert_allclose(c1["normal_sum"], c0["normal_sum"], rtol=1e-12, atol=1e-12)
    q0, q1 = quantize_semantic_delta(k0, c0), quantize_semantic_delta(k1, c1)
    assert np.abs(q0.channels["S"] - q1.channels["S"]).max() <= D_STEPS
    for name in ("normal_sum", "rgb_sum", "count"):
        assert np.array_equal(q0.channels[name], q1.channels[name])


_THREADS_SCRIPT = """
import hashlib, sys
import numpy as np
sys.path.insert(0, {tests!r})
from semantics_helpers import CLASS_NAMES, pose, render_room
from panovocc_cli.classes import DEFAULT_VOCAB
from panovocc_cli.semantics.evidence import frame_semantic_delta
from panovocc_cli.semantics.observation import observe
from panovocc_cli.semantics.simulated import SimulatedConfig, simulate_logits
T = pose(yaw=0.7)
lab, depth, rgb = render_room(512, T)
depth = depth.astype(np.float32)
depth[::11, ::3] = 0.0
logits = simulate_logits(lab, CLASS_NAMES, list(DEFAULT_VOCAB) + ["pillow"], 2, SimulatedConfig(seed=4))
obs = observe(logits)
k, c = frame_semantic_delta(depth, rgb, obs, T, 0.08)
h = hashlib.sha256(logits.tobytes())
h.update(obs.classes.tobytes())
h.update(obs.q.tobytes())
h.update(k.tobytes())
for name in sorted(c):
    h.update(np.ascontiguousarray(c[name]).tobytes())
print(h.hexdigest(), len(k))
"""


def test_delta_and_simulator_bytes_do_not_depend_on_the_thread_count():
    """The compiled kernels split the image into a fixed number of row chunks and merge them in chunk
    order, so 1 and 2 numba threads give the same bytes (logits, observation, keys and every float sum)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = _THREADS_SCRIPT.format(tests=str(Path(__file__).resolve().parents[1]))
    out = []
    for n in (1, 2):
        env = dict(os.environ, NUMBA_NUM_THREADS=str(n))
        r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[-2000:]
        out.append(r.stdout.split())
    assert out[0] == out[1] and int(out[0][1]) > 100
