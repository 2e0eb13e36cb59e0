"""slam/tracker.py: the final refinement of the keyframes against each other, the bounded keyframe store and
the loop candidates' spatial index (issue 22: a precise front end that lasts)."""

import numpy as np
import pytest

from panovocc_cli.evaluation.trajectory import evaluate_trajectory
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.slam import SlamParams, Tracker
from panovocc_cli.slam.registration import Cloud
from panovocc_cli.slam.tracker import LEVEL_FIRST, _Keyframe


def _ate(committed, seq):
    ids = sorted(committed)
    return evaluate_trajectory(np.stack([committed[i] for i in ids]), seq.poses[ids], "se3").ate["rmse"]


def _track(seq, ids, params=None):
    tr = Tracker(seq.meta.width, seq.meta.height, params, T_world_first=seq.poses[0])
    for i in ids:
        tr.track(i, seq.depth(i))
    return tr


def test_final_refinement_reduces_ate_and_is_deterministic(loop_seq):
    seq = Sequence(loop_seq)
    tr = _track(seq, range(48))
    before = _ate(tr.committed(), seq)
    moved = tr.finish()
    after = _ate(tr.committed(), seq)
    assert tr.refinements == tr.params.refine_passes and moved  # every frame the refinement moved by more than 0.5 mm is handed out
    assert after < 0.8 * before, (before, after)
    # the poses handed out are the refined ones (within the final revision thresholds)
    for fid, T in tr.committed().items():
        assert np.linalg.norm(T[:3, 3] - tr.pose(fid)[:3, 3]) <= tr.params.final_revise_m
    # without the refinement nothing moves; with it the same frames give the same bytes
    off = _track(seq, range(48), SlamParams(refine=False))
    assert off.finish() == [] and _ate(off.committed(), seq) == before
    again = _track(seq, range(48))
    again.finish()
    assert all(np.array_equal(a, b) for a, b in zip(tr.committed().values(), again.committed().values()))


def test_keyframe_store_is_bounded_and_compacting_changes_nothing(loop_seq):
    """Only ``kf_held`` keyframes keep their registration structures; the others keep their downsampled
    points alone, as float32 (at 256 x 128 and 0.1 m voxels about 105 kB a keyframe, under a sixth of the
    frame's full-resolution cloud), and
    rebuilding the structures gives the same bytes, so the poses are those of an unbounded store."""
    seq = Sequence(loop_seq)
    # every loop edge optimised at once and a periodic refinement every 5 keyframes: both reach back into
    # compacted keyframes
    kw = dict(loop_min_gap=2, loop_optimise_m=0.0, loop_optimise_deg=0.0, refine_every=5)
    small = _track(seq, range(30), SlamParams(kf_held=3, **kw))
    big = _track(seq, range(30), SlamParams(kf_held=1000, **kw))
    assert small.loops and small.optimisations >= 1 and small.refinements >= 2
    m = small.memory()
    assert m["held"] == 3 and m["keyframes"] >= 10
    assert sum(kf.cloud.handle is not None for kf in small.keyframes) == 3
    assert all(kf.cloud._o3d is None for kf in small.keyframes if kf.cloud.handle is None)
    full = 24 * seq.meta.width * seq.meta.height  # the frame's full-resolution cloud, (H W, 3) float64
    assert m["points"] / m["keyframes"] < 0.18 * full  # ~105 kB a keyframe here (0.1 m voxels), 786 kB full
    assert m["held_bytes"] > 5 * m["points"] / m["keyframes"] * m["held"]  # what compaction saves per keyframe
    assert m["points"] == sum(12 * len(kf.cloud) for kf in small.keyframes)  # (n, 3) float32 each
    assert all(kf.cloud.points.dtype == np.float32 for kf in small.keyframes)
    assert big.memory()["held"] == big.memory()["keyframes"]
    small.finish(), big.finish()
    assert small.committed().keys() == big.committed().keys()
    assert all(np.array_equal(a, b) for a, b in zip(small.committed().values(), big.committed().values()))


def test_loop_candidates_from_the_index_equal_the_scan():
    """The KD-tree over keyframe positions finds exactly the keyframes a scan of every keyframe finds, in the
    same order, also where the path length is not monotonic (a relocalisation starts from an older keyframe)."""
    rng = np.random.default_rng(0)
    tr = Tracker(64, 32, SlamParams(loop_candidates=1000, loop_radius_m=1.0, loop_min_gap=3))
    odo = np.cumsum(rng.uniform(0.0, 0.5, 300))
    odo[150:] -= odo[149]  # relocalised: the path length starts again from an older keyframe's
    for i in range(300):
        T = np.eye(4)
        T[:3, 3] = rng.uniform(-8.0, 8.0, 3) * [1.0, 1.0, 0.2]
        tr.keyframes.append(_Keyframe(i, Cloud(np.zeros((0, 3))), T, float(odo[i])))
    sizes = []
    for new in range(300):
        a, b = tr._loop_candidates(new), tr._loop_candidates(new, index=False)
        assert a == b
        sizes.append(len(a))
    assert min(sizes) == 0 and 5 < max(sizes) < 297  # the case tests something: some near, not all
    tr.params.loop_candidates = 3
    assert all(tr._loop_candidates(n) == tr._loop_candidates(n, index=False)[:3] for n in range(300))


def _storeys(world: np.ndarray, tilt_deg: float = 0.0, **params) -> Tracker:
    """Keyframes of a walk over two storeys 3 m apart: 40 along a 20 m corridor on the lower one (path 0-20 m), then 40
    on the upper one, right above it, 10 m out and back (path 500-520 m: far along the path, so the horizontal sigma
    reaches the whole lower storey); level cameras (LEVEL_FIRST's axes), or tilted ``tilt_deg`` towards the corridor
    and back on alternate keyframes (a walk's sway), all in ``world`` (4, 4)."""
    tr = Tracker(64, 32, SlamParams(loop_candidates=1000, **params))
    for i in range(80):
        k = i % 40
        a = np.radians(tilt_deg if i % 2 else -tilt_deg)
        T = np.eye(4)
        T[[0, 0, 2, 2], [0, 2, 0, 2]] = [np.cos(a), np.sin(a), -np.sin(a), np.cos(a)]  # about the world's y
        T = T @ LEVEL_FIRST
        T[:3, 3] = [0.5 * k if i < 40 else 0.5 * min(k, 39 - k), 0.0, 3.0 * (i // 40)]
        tr.keyframes.append(_Keyframe(i, Cloud(np.zeros((0, 3))), world @ T, 0.5 * k + 500.0 * (i // 40)))
    return tr


def test_loop_candidates_stay_on_their_storey():
    """A keyframe a storey (3 m) above older ones, 500 m further along the path, has none of them as a loop
    candidate (the up sigma: a panorama sees floor and ceiling); with ``odom_sigma_up_per_m`` = 0 (the translation's
    sigma alike in every direction, as before) it has them all. Keyframes on its own storey still are. The test
    follows the keyframes' mean up axis, not the world's z: the same lists in a world turned 30 degrees about x and
    with cameras that sway."""
    tilt = np.eye(4)
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    tilt[1:3, 1:3] = [[c, -s], [s, c]]
    lists = []
    for world in (np.eye(4), tilt):
        gated, free = _storeys(world), _storeys(world, odom_sigma_up_per_m=0.0)
        lists.append([gated._loop_candidates(new) for new in range(80)])
        for new in range(41, 80):
            assert gated._loop_candidates(new) == gated._loop_candidates(new, index=False)
            assert all(j >= 40 for j in gated._loop_candidates(new))  # its own storey only
            assert set(range(min(40, new - 6))) <= set(free._loop_candidates(new))  # the storey below (loop_min_gap 6)
        assert gated._loop_candidates(79)[:3] == [40, 41, 42]  # back where the upper walk began: 0, 0.5, 1 m
    assert lists[0] == lists[1]
    # cameras swaying 4.5 degrees: over the corridor's 20 m two cameras' own up axes would read the storey 1.5 m
    # lower and admit it; the mean up of the walk's keyframes does not sway
    assert [_storeys(np.eye(4), 4.5)._loop_candidates(new) for new in range(80)] == lists[0]
    with pytest.raises(ValueError, match="odom_sigma_up_per_m"):
        SlamParams(odom_sigma_up_per_m=-1.0).check()


def test_final_refinement_rebuilds_each_keyframe_once_a_pass(monkeypatch):
    """The refinement registers its edges in the order of their newer keyframe, so with ``kf_held`` keyframes held
    a walk's keyframes each have their registration structures rebuilt once a pass (the odometry edges, then the
    pairs, each in their own order, rebuilt every keyframe twice). The edges keep their order, so the poses are
    those of that order bit for bit (checked on the tuning scenes when it changed, 2026-12-05)."""
    from panovocc_cli.slam import registration

    rng = np.random.default_rng(5)
    x, side = rng.uniform(-2.0, 22.0, 6000), rng.integers(0, 3, 6000)
    corridor = np.stack([x, np.where(side == 0, -1.0, np.where(side == 1, 1.0, rng.uniform(-1, 1, 6000))),
                         np.where(side == 2, -1.2, rng.uniform(-1.2, 1.3, 6000))], 1)  # two walls and a floor
    corridor = np.concatenate([corridor, [[5.0 * k, 0.9, 0.2] for k in range(5)]])  # a few posts along it
    tr = Tracker(64, 32, SlamParams(kf_held=8, refine_passes=2))
    n = 40
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.4 * i
        tr.keyframes.append(_Keyframe(i, tr.reg.prepare(corridor - T[:3, 3]), T, 0.4 * i))
        if i:
            info = tr.reg.information(tr.keyframes[i - 1].cloud, tr.keyframes[i].cloud,
                                      np.linalg.inv(tr.keyframes[i - 1].T_world) @ T, tr.params.loop_max_corr_m)
            tr._edges.append((i, i - 1, np.linalg.inv(tr.keyframes[i - 1].T_world) @ T, info, False))
    for k in range(n):
        tr._cloud(k)  # the last kf_held keyframes held, as after tracking
    rebuilt = []
    restore = registration.Registration.restore
    monkeypatch.setattr(registration.Registration, "restore",
                        lambda self, cloud: (rebuilt.append(id(cloud)) if cloud.handle is None else None,
                                             restore(self, cloud))[1])
    before = tr.rebuilds
    tr.finish()
    assert tr.refinements == 2 and len(tr._edges) > 2 * n  # pairs beyond the odometry edges were registered
    assert len(rebuilt) == 2 * n  # each keyframe once a pass (4 n before)
    assert tr.rebuilds - before == len(rebuilt)  # the tracker's own count (scripts/slam_refine_profile.py reads it)
