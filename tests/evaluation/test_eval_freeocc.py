"""``panovocc eval --json`` against an independent reference of FreeOcc's released evaluation code.

The reference below is written from FreeOcc's algorithm (``SSCMetricsTorch`` in
``src/scannet_utils/eval_utils.py``, the eval8 average in ``scripts/src/eval_occ_replica.py``), not
from panovocc's: both grids on the ground truth's voxels in FreeOcc's label space (1 + line of
``replica_name.txt``), ground truth 255 ignored (set to 0 on both sides and masked), a per-class loop
over every id, counts summed over scenes, ``tp / (tp + fp + fn + 1e-5)`` (plus their ``_safe_div``
1e-8), mIoU = the plain mean over the eight eval8 ids. Cases: classes absent from the ground truth,
grids of other origins and shapes, class lists in other orders, several scenes pooled, and files
written by ``convert to-replicaocc`` read the way FreeOcc's loader reads them.
"""

import json
import pickle

import numpy as np
import pytest

from panovocc_cli.cli import main
from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import write_grid
from panovocc_cli.io.replicaocc import REPLICA_NAMES

H = 0.08
EVAL8 = ["ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table"]
REPLICA_ID = {n: k + 1 for k, n in enumerate(REPLICA_NAMES)}  # FreeOcc: label = line number + 1


def to_freeocc_labels(grid: Grid, gt: Grid, prediction: bool) -> np.ndarray:
    """``grid`` looked up voxel by voxel at ``gt``'s voxel centres, in Replica ids (0 where it has nothing)."""
    out = np.zeros(gt.labels.shape, dtype=np.int64)
    for ijk in np.ndindex(*gt.labels.shape):
        centre = gt.origin + np.asarray(ijk) * gt.voxel_size
        src = np.round((centre - grid.origin) / grid.voxel_size).astype(int)
        if np.any(src < 0) or np.any(src >= grid.labels.shape):
            continue  # not covered: FreeOcc's grid has no voxel there, i.e. free
        v = int(grid.labels[tuple(src)])
        if v in (0, 254):
            out[ijk] = v
        elif v == 255:
            out[ijk] = 0 if prediction else 255  # what our writer does for FreeOcc's scripts
        else:
            name = {"tv": "tv-screen", "lighting": "lamp"}.get(grid.class_names[v], grid.class_names[v])
            out[ijk] = REPLICA_ID[name]
    return out


def freeocc_reference(scenes, n_classes=102):
    """FreeOcc's counts and scores, as fractions, for (pred, gt) integer arrays of one shape each."""
    tps, fps, fns = (np.zeros(n_classes) for _ in range(3))
    ctp = cfp = cfn = 0.0
    for pred, gt in scenes:
        valid = gt != 255
        p = np.where(gt == 255, 0, pred)
        t = np.where(gt == 255, 0, gt)
        yp, yt = (p > 0) & valid, (t > 0) & valid
        ctp += np.sum(yt & yp)
        cfp += np.sum(~yt & yp)
        cfn += np.sum(yt & ~yp)
        pm = np.where(valid, p, -2)
        tm = np.where(valid, t, -1)
        for j in range(n_classes):
            tps[j] += np.sum((pm == j) & (tm == j))
            fps[j] += np.sum((pm == j) & (tm != j))
            fns[j] += np.sum((pm != j) & (tm == j))
    iou = ctp / (ctp + cfp + cfn + 1e-8) if ctp > 0 else 0.0
    iou_ssc = tps / ((tps + fps + fns + 1e-5) + 1e-8)
    ids = [REPLICA_ID[n] for n in EVAL8]
    return {"iou": iou, "iou_ssc": {n: iou_ssc[REPLICA_ID[n]] for n in EVAL8}, "miou": float(np.mean(iou_ssc[ids]))}


def scene_pair(seed, gt_names, pred_names, absent=(), pred_shift=(0, 0, 0), pred_shape=None):
    """A random GT and a noisy prediction of it, each with its own class list, extent and origin."""
    rng = np.random.default_rng(seed)
    shape = (11, 9, 6)
    gname = rng.choice([n for n in gt_names[1:] if n not in absent], size=shape)
    lab = np.array([gt_names.index(n) for n in gname.reshape(-1)], dtype=np.uint8).reshape(shape)
    lab[rng.random(shape) < 0.45] = 0
    lab[rng.random(shape) < 0.1] = 255
    i0 = np.array([-4, 7, 1])
    gt = Grid(lab, (i0 + 0.5) * H, H, gt_names)
    # the prediction: the GT's names, 25 % replaced by any of its own classes (absent ones too), 254 and 255
    names = np.array(gt_names + [""] * (256 - len(gt_names)), dtype=object)[lab]
    pl = np.array([pred_names.index(n) if n in pred_names else 0 for n in names.reshape(-1)],
                  dtype=np.uint8).reshape(shape)
    noise = rng.random(shape) < 0.25
    pl[noise] = rng.choice(np.r_[np.arange(len(pred_names)), 254, 255], size=int(noise.sum()))
    ps = np.asarray(pred_shape or shape)
    sh = np.asarray(pred_shift)
    big = np.zeros(tuple(np.maximum(ps, np.asarray(shape) + np.abs(sh)) + np.abs(sh)), np.uint8)
    big[tuple(slice(abs(s), abs(s) + n) for s, n in zip(sh, shape))] = pl
    # crop the prediction to its own box: origin moved by pred_shift, shape pred_shape
    start = np.abs(sh) + sh
    pl2 = big[tuple(slice(s, s + n) for s, n in zip(start, ps))]
    pred = Grid(pl2, (i0 + sh + 0.5) * H, H, pred_names)
    return pred.validate(), gt.validate()


def eval_json(capsys, tmp_path, pairs, classes="eval8"):
    args = []
    for k, (pred, gt) in enumerate(pairs):
        write_grid(tmp_path / f"p{k}.npz", pred)
        write_grid(tmp_path / f"g{k}.npz", gt)
        args += (["--pair"] if k else []) + [str(tmp_path / f"p{k}.npz"), str(tmp_path / f"g{k}.npz")]
    with pytest.raises(SystemExit) as e:
        main(["eval", *args, "--json", "--classes", classes])
    out = capsys.readouterr()
    assert e.value.code == 0, out.err
    return json.loads(out.out)


GT_NAMES = ["empty", "wall", "floor", "ceiling", "chair", "table", "window", "rug", "bed", "sofa"]
PRED_NAMES = ["empty", "sofa", "table", "chair", "floor", "tv", "wall", "ceiling", "bed", "window"]  # renumbered

CASES = {
    "absent classes": [dict(seed=0, absent=("bed", "sofa", "window"))],
    "other extents": [dict(seed=1, pred_shift=(2, -3, 1), pred_shape=(8, 12, 4))],
    "renumbered, absent and shifted": [dict(seed=2, absent=("table",), pred_shift=(-1, 0, -2), pred_shape=(13, 7, 9))],
    "three scenes pooled": [dict(seed=3, absent=("bed",)), dict(seed=4, pred_shift=(0, 2, 0)),
                            dict(seed=5, absent=("ceiling", "sofa"), pred_shape=(5, 5, 5))],
}


@pytest.mark.parametrize("case", list(CASES))
def test_eval_json_equals_freeocc_reference(capsys, tmp_path, case):
    pairs = [scene_pair(gt_names=GT_NAMES, pred_names=PRED_NAMES, **kw) for kw in CASES[case]]
    got = eval_json(capsys, tmp_path, pairs)
    ref = freeocc_reference([(to_freeocc_labels(p, g, True), to_freeocc_labels(g, g, False)) for p, g in pairs])
    assert got["mask"] == "freeocc" and got["classes"] == EVAL8
    assert got["miou"] == pytest.approx(100 * ref["miou"], abs=1e-9)
    # occupancy IoU is the exact ratio; FreeOcc's adds 1e-8 to the denominator (relative 1e-8 / union)
    assert got["iou"] == pytest.approx(100 * ref["iou"], rel=1e-9)
    for n in EVAL8:
        assert got["per_class_freeocc"][n] == pytest.approx(100 * ref["iou_ssc"][n], abs=1e-9), n
    if any(kw.get("absent") for kw in CASES[case]) and case != "three scenes pooled":
        assert got["absent"] and got["miou"] < got["miou_present"]  # the two rules differ, both reported


def test_files_for_freeocc_scripts_score_the_same(capsys, tmp_path):
    """GT and prediction written by ``convert to-replicaocc`` (``--prediction --like GT``) and read the way
    FreeOcc's loader reads them give FreeOcc's numbers equal to ``panovocc eval``'s."""
    pred, gt = scene_pair(6, GT_NAMES, PRED_NAMES, absent=("sofa",), pred_shift=(3, 1, -1), pred_shape=(9, 9, 9))
    got = eval_json(capsys, tmp_path, [(pred, gt)])
    for args in (["p0.npz", "pred.pkl", "--prediction", "--like", "g0.npz"], ["g0.npz", "gt.pkl"]):
        with pytest.raises(SystemExit) as e:
            main(["convert", "to-replicaocc", *[str(tmp_path / a) if a.endswith(("npz", "pkl")) else a for a in args]])
        assert e.value.code == 0, capsys.readouterr().err
    loaded = {}
    for k in ("pred", "gt"):
        with open(tmp_path / f"{k}.pkl", "rb") as f:
            loaded[k] = np.asarray(pickle.load(f)["global_labels"]).astype(np.int64)  # FreeOcc: .long()
    assert loaded["pred"].shape == loaded["gt"].shape == gt.labels.shape and not (loaded["pred"] == 255).any()
    ref = freeocc_reference([(loaded["pred"], loaded["gt"])])
    assert got["miou"] == pytest.approx(100 * ref["miou"], abs=1e-9)
    assert got["iou"] == pytest.approx(100 * ref["iou"], rel=1e-9)
