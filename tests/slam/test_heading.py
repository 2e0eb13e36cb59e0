"""slam/heading.py and the refinement's heading and level priors (``SlamParams.heading_prior``,
``level_prior``): a keyframe's wall heading read from its normals, modulo 90 degrees, and its vertical from its
floors and ceilings; a prior that turns one keyframe about the up axis and nothing else, another that tilts it
and does not turn it; a tracker whose later keyframes were turned or tilted by a small error finds that error."""

import numpy as np
import pytest

from panovocc_cli.io.sequence import Sequence
from panovocc_cli.slam import SlamParams, Tracker
from panovocc_cli.slam.heading import floor_vertical, rotation_about, tilt_between, wall_heading, wrap_quarter
from panovocc_cli.slam.posegraph import heading_factor, level_factor, solve_batch


def _normals(heading_deg, n_walls=3000, n_clutter=1500, noise_deg=1.0, seed=0):
    """Wall normals in the four directions heading + k 90 deg with noise, floor and ceiling normals, and
    clutter at random azimuths (furniture at odd angles)."""
    rng = np.random.default_rng(seed)
    th = np.radians(heading_deg + 90.0 * rng.integers(0, 4, n_walls) + noise_deg * rng.standard_normal(n_walls))
    walls = np.stack([np.cos(th), np.sin(th), 0.02 * rng.standard_normal(n_walls)], 1)
    c = rng.uniform(-np.pi, np.pi, n_clutter)
    clutter = np.stack([np.cos(c), np.sin(c), np.zeros(n_clutter)], 1)
    flat = np.tile([0.0, 0.0, 1.0], (2000, 1))
    n = np.concatenate([walls, clutter, flat])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _tracked(loop_seq, **params) -> Tracker:
    """A tracker over the first 24 frames of a real room, started at its true first pose."""
    seq = Sequence(loop_seq)
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**params), T_world_first=seq.poses[0])
    for i in range(24):
        tr.track(i, seq.depth(i))
    return tr


def _priors(tr: Tracker) -> list:
    """The refinement's priors for the tracker's keyframes as they are now."""
    T0_inv = np.linalg.inv(tr.keyframes[0].T_world)
    return tr._manhattan_priors(np.stack([T0_inv @ kf.T_world for kf in tr.keyframes]), T0_inv)


def _turn_keyframes(tr: Tracker, R: np.ndarray, first: int) -> None:
    """Keyframes ``first`` onwards turned by ``R`` (3, 3) about the first keyframe's position (what a storey of
    stairs or a corridor leaves); the tracker's keyframe arrays are then read again."""
    o = tr.keyframes[0].T_world[:3, 3]
    for kf in tr.keyframes[first:]:
        T = kf.T_world.copy()
        T[:3, :3] = R @ T[:3, :3]
        T[:3, 3] = R @ (T[:3, 3] - o) + o
        kf.T_world = T
    tr.optimisations += 1


@pytest.mark.parametrize("heading", [0.0, 0.3, 30.0, -44.0, 89.7])
def test_wall_heading_modulo_90_degrees(heading):
    phi, share = wall_heading(_normals(heading), np.array([0.0, 0.0, 1.0]))
    assert abs(np.degrees(wrap_quarter(phi - np.radians(heading)))) < 0.05 and share > 0.3
    # the same walls seen by a camera turned about the vertical: the heading turns with it
    R = rotation_about([0.0, 0.0, 1.0], np.radians(0.2))
    phi2, _ = wall_heading(_normals(heading) @ R.T, np.array([0.0, 0.0, 1.0]))
    assert abs(np.degrees(wrap_quarter(phi2 - phi)) - 0.2) < 0.01


def test_wall_heading_needs_walls():
    flat = np.tile([0.0, 0.0, 1.0], (500, 1))
    phi, share = wall_heading(flat, np.array([0.0, 0.0, 1.0]))
    assert np.isnan(phi) and share == 0.0


def test_heading_factor_turns_about_up_only():
    """A node held by nothing but its heading prior turns by the correction about the up axis; its position
    and its tilt stay (the prior has no information there)."""
    up = np.array([0.1, -0.2, 1.0])
    up /= np.linalg.norm(up)
    P1 = np.eye(4)
    P1[:3, :3] = rotation_about([1.0, 0.3, 0.0], np.radians(5.0)) @ rotation_about(up, np.radians(40.0))
    P1[:3, 3] = [3.0, -1.0, 0.5]
    c = np.radians(0.1)
    out = solve_batch(np.stack([np.eye(4), P1]), [], 0.1, [heading_factor(1, P1, up, c, np.radians(0.05))])
    assert np.allclose(out[1][:3, :3], rotation_about(up, c) @ P1[:3, :3], atol=1e-9)
    assert np.allclose(out[1][:3, 3], P1[:3, 3], atol=1e-9)


def test_tracker_reads_a_heading_error_of_its_later_keyframes(loop_seq):
    """Keyframes tracked over a real room, then every keyframe after the fourth turned by 0.08 degrees about
    the vertical through the first (what a storey of stairs leaves): the priors ask each of those back by
    0.08 degrees more than before, the first four as before."""
    tr = _tracked(loop_seq, heading_prior=True, heading_reference=4)
    n = len(tr.keyframes)
    assert n >= 8

    def corrections():
        priors = _priors(tr)
        assert tr.heading["priors"] == len(priors) >= n - 3
        return np.degrees(tr.heading_corrections)

    before = corrections()
    assert np.abs(before).max() < 0.2  # the room's walls read within 0.2 degrees under the tracked poses
    _turn_keyframes(tr, rotation_about([0.0, 0.0, 1.0], np.radians(0.08)), 4)
    after = corrections()
    assert np.allclose(after[:4], before[:4], atol=1e-3)
    assert np.allclose(after[4:] - before[4:], -0.08, atol=1e-3)
    with pytest.raises(ValueError, match="isam2"):
        SlamParams(heading_prior=True, optimiser="open3d").check()


@pytest.mark.parametrize("tilt_deg", [0.0, 0.02, 0.5, 3.0])
def test_floor_vertical_from_floors_and_ceilings(tilt_deg):
    """Floors (normals up) and ceilings (down: PCA normals have no sign) with 0.2 degrees of noise, walls and
    clutter, all tilted by ``tilt_deg`` about an axis in the horizontal plane: the vertical reads the tilt
    to a hundredth of a degree, whichever way the normals point."""
    rng = np.random.default_rng(1)
    flat = np.array([0.0, 0.0, 1.0]) + np.radians(0.2) * rng.standard_normal((4000, 3)) * [1, 1, 0]
    flat *= rng.choice([-1.0, 1.0], 4000)[:, None]
    c = rng.standard_normal((1500, 3))  # clutter at every angle, some of it within 10 degrees of vertical
    n = np.concatenate([flat, _normals(20.0, n_clutter=0)[:3000], c])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    axis = np.array([0.6, -0.8, 0.0])
    R = rotation_about(axis, np.radians(tilt_deg)) if tilt_deg else np.eye(3)
    v, share = floor_vertical(n @ R.T, np.array([0.0, 0.0, 1.0]))
    assert share > 0.3
    assert np.degrees(np.linalg.norm(np.cross(v, R @ [0.0, 0.0, 1.0]))) < 0.01
    t = tilt_between(v, np.array([0.0, 0.0, 1.0]))
    assert abs(np.degrees(np.linalg.norm(t)) - tilt_deg) < 0.01
    if tilt_deg >= 0.5:
        assert abs(abs(t @ axis) / np.linalg.norm(t) - 1.0) < 1e-3


def test_floor_vertical_needs_floors():
    walls = _normals(10.0, n_clutter=0)[:3000]
    v, share = floor_vertical(walls, np.array([0.0, 0.0, 1.0]))
    assert v is None and share == 0.0


def test_level_factor_tilts_without_turning():
    """A node held by nothing but its level prior is tilted by the correction; its heading about up and its
    position stay."""
    up = np.array([0.0, 0.0, 1.0])
    P1 = np.eye(4)
    P1[:3, :3] = rotation_about(up, np.radians(40.0)) @ rotation_about([0.2, 1.0, 0.3], np.radians(30.0))
    P1[:3, 3] = [3.0, -1.0, 0.5]
    tilt = np.radians(0.05) * np.array([0.6, 0.8, 0.0])
    out = solve_batch(np.stack([np.eye(4), P1]), [], 0.1, [level_factor(1, P1, tilt, up, np.radians(0.05))])
    from panovocc_cli.geometry.drift import so3_exp

    assert np.allclose(out[1][:3, :3], so3_exp(tilt) @ P1[:3, :3], atol=1e-9)
    assert np.allclose(out[1][:3, 3], P1[:3, 3], atol=1e-9)


def test_tracker_reads_a_tilt_of_its_later_keyframes(loop_seq):
    """Keyframes tracked over a real room, then every keyframe after the fourth tilted by 0.05 degrees about a
    horizontal axis through the first (a floor tilted along a corridor): the level priors ask each of those
    back by 0.05 degrees, the first four as before."""
    tr = _tracked(loop_seq, level_prior=True, heading_reference=4)
    n = len(tr.keyframes)
    assert n >= 8

    def tilts():
        priors = _priors(tr)
        assert tr.level["priors"] == len(priors) >= n - 3 and tr.heading is None
        return np.degrees(tr.level_corrections)

    before = tilts()
    assert before.max() < 0.1  # the room's floor and ceiling read within 0.1 degrees under the tracked poses
    _turn_keyframes(tr, rotation_about([1.0, 2.0, 0.0], np.radians(0.05)), 4)
    after = tilts()
    assert np.allclose(after[:4], before[:4], atol=1e-3)
    assert np.all(np.abs(after[4:] - 0.05) < before[4:] + 1e-3)  # a tilt of 0.05 deg, plus or minus what was
    with pytest.raises(ValueError, match="isam2"):
        SlamParams(level_prior=True, optimiser="open3d").check()


def test_level_reference_world_reads_a_tilt_of_every_keyframe(loop_seq):
    """Every keyframe tilted by 0.05 degrees about a horizontal axis through the first: held to the first keyframes'
    vertical, the corrections stay as they were (the reference tilts with them); held to the world's +Z
    (``level_reference`` "world", the world of ``--first-pose``), each grows by 0.05 degrees."""
    trackers = {ref: _tracked(loop_seq, level_prior=True, heading_reference=4, level_reference=ref)
                for ref in ("keyframes", "world")}

    def tilts(tr):
        _priors(tr)
        return np.degrees(tr.level_corrections)

    before = {ref: tilts(tr) for ref, tr in trackers.items()}
    assert before["world"].max() < 0.1  # the room's true world is level
    for tr in trackers.values():
        _turn_keyframes(tr, rotation_about([1.0, 2.0, 0.0], np.radians(0.05)), 0)
    after = {ref: tilts(tr) for ref, tr in trackers.items()}
    assert np.allclose(after["keyframes"], before["keyframes"], atol=1e-3)
    assert np.all(np.abs(after["world"] - 0.05) < before["world"] + 1e-3)
    with pytest.raises(ValueError, match="level_reference"):
        SlamParams(level_prior=True, level_reference="gravity").check()

@pytest.mark.parametrize("reference", ["keyframes", "world"])
def test_level_priors_when_no_keyframe_sees_a_floor(reference):
    """Keyframes none of which reads a vertical (outdoors, or a frame with little depth): no level prior, no error,
    whichever the reference."""
    tr = Tracker(64, 32, SlamParams(level_prior=True, level_reference=reference))
    vert = np.full((5, 3), np.nan)
    out = tr._level_factors(vert, np.zeros(5), np.stack([np.eye(4)] * 5), np.eye(3))
    assert out == [] and tr.level["priors"] == 0
    assert reference == "keyframes" or np.all(np.isnan(tr.level_corrections))
