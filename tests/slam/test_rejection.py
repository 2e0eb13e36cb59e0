"""slam/tracker.py refuses what it cannot tell apart: an ambiguous relocalisation, a loop outside the odometry's reach.

Frames are ray-cast, noise-free, in a box room (6 m x 4 m x 2.6 m, camera 1.5 m above the floor, 256 x 128 ERP).
An empty box room looks the same after a half turn about its centre: a frame at offset d and heading h is the
frame at offset -d and heading h + 180 degrees, so relocalisation must refuse to choose. Two cabinets against
the walls break the symmetry, and the same relocalisation must then succeed.
"""

import numpy as np

from panovocc_cli.geometry import erp
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.slam import SlamParams, Tracker
from panovocc_cli.slam.registration import erp_points
from panovocc_cli.slam.tracker import _Keyframe

W, H = 256, 128
ROOM = (np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 2.6]))  # interior, world metres, +Z up
CABINETS = [(np.array([0.8, 1.2, 0.0]), np.array([2.6, 2.0, 2.0])),  # both along the +Y wall
            (np.array([-2.6, 1.4, 0.0]), np.array([-1.2, 2.0, 0.9]))]


def _pose(x: float, y: float, heading_deg: float) -> np.ndarray:
    a = np.radians(heading_deg)
    return look_at([x, y, 1.5], [np.cos(a), np.sin(a), 0.0])


def _depth(T_world_cam: np.ndarray, boxes=()) -> np.ndarray:
    """(H, W) float32 radial depth of the room (and solid ``boxes``) seen from ``T_world_cam``."""
    d = erp.ray_directions(W, H).reshape(-1, 3) @ T_world_cam[:3, :3].T
    o = T_world_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        lo, hi = (ROOM[0] - o) * inv, (ROOM[1] - o) * inv
        t = np.where(np.isfinite(hi), np.maximum(lo, hi), np.inf).min(axis=1)  # leaving the room's interior
        for b0, b1 in boxes:  # slab test: entering a solid box
            lo, hi = (b0 - o) * inv, (b1 - o) * inv
            near = np.nan_to_num(np.minimum(lo, hi), nan=-np.inf).max(axis=1)
            far = np.nan_to_num(np.maximum(lo, hi), nan=np.inf).min(axis=1)
            hit = (near <= far) & (near > 0)
            t = np.where(hit & (near < t), near, t)
    return t.reshape(H, W).astype(np.float32)


def _tracker(params=None, boxes=()):
    tr = Tracker(W, H, params, T_world_first=_pose(0.0, 0.0, 0.0))
    assert tr.track(0, _depth(_pose(0.0, 0.0, 0.0), boxes)).placed
    return tr


def _cloud(tr: Tracker, T_world_cam: np.ndarray, boxes=()):
    return tr.reg.prepare(erp_points(_depth(T_world_cam, boxes), tr._rays, tr.stride, 0.2, 10.0))


def test_relocalisation_refuses_a_heading_it_cannot_tell_apart():
    truth = _pose(0.6, 0.4, 30.0)
    tr = _tracker()
    found, why = tr._relocalise(_cloud(tr, truth), pred=tr.keyframes[0].T_world)
    assert found is None and "ambiguous" in why  # the pose and its half turn fit equally well

    # the same frame where two cabinets break the room's symmetry: placed, at the true pose
    tr = _tracker(boxes=CABINETS)
    found, why = tr._relocalise(_cloud(tr, truth, CABINETS), pred=tr.keyframes[0].T_world)
    assert found is not None, why
    k, r, status = found
    T = tr.keyframes[k].T_world @ r.T_target_source
    assert status == "relocalised" and np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.02


def test_a_loop_outside_the_odometry_uncertainty_is_not_accepted():
    """Keyframe 1 was truly 0.36 m from keyframe 0 but its estimate is 0.6 m off: registration finds the true
    relative pose either way; after 3 m of odometry (3 sigma = 0.18 m) such a correction is not believable and
    the loop is refused, after 30 m (3 sigma = 1.8 m) it is accepted, with the true relative pose."""
    true1 = _pose(0.3, 0.2, 20.0)
    est1 = true1.copy()
    est1[:3, 3] += [0.6, 0.0, 0.0]
    for path_m, accepted in ((3.0, False), (30.0, True)):
        tr = _tracker(SlamParams(loop_min_gap=0), boxes=CABINETS)
        tr.keyframes.append(_Keyframe(1, _cloud(tr, true1, CABINETS), est1.copy(), odo_m=path_m))
        loops, urgent = tr._close_loops(1)
        assert bool(loops) == accepted and urgent == accepted, (path_m, loops)
        if accepted:
            T = [e[2] for e in tr._edges if e[4]][0]
            truth = np.linalg.inv(_pose(0.0, 0.0, 0.0)) @ true1
            assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.02
