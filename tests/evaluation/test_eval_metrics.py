"""FreeOcc scoring against an independent plain-Python count, invariances and edge cases."""

import math

import numpy as np
import pytest

from panovocc_cli.classes import canonical_name
from panovocc_cli.errors import PanovoccError
from panovocc_cli.evaluation.metrics import count_pair, evaluate
from panovocc_cli.grid import Grid

H = 0.08
GT_NAMES = ["empty", "wall", "floor", "chair", "tv-screen", "pillow"]
PRED_NAMES = ["empty", "chair", "tv", "wall", "floor", "sofa"]


def grid(labels, index0, names, h=H):
    return Grid(np.asarray(labels, dtype=np.uint8), (np.asarray(index0) + 0.5) * h, h, names)


def random_pair(seed):
    rng = np.random.default_rng(seed)
    g = rng.choice([0, 0, 1, 2, 3, 4, 5, 254, 255], size=(7, 6, 5)).astype(np.uint8)
    p = rng.choice([0, 1, 2, 3, 4, 5, 254, 255], size=(6, 8, 4)).astype(np.uint8)
    return grid(g, (-3, 2, 10), GT_NAMES), grid(p, (-1, 0, 11), PRED_NAMES)


def brute_force(pred: Grid, gt: Grid, mask: str):
    """Per-voxel Python loop, written independently of the vectorised code."""
    pmap = {}
    for (i, j, k), v in np.ndenumerate(pred.labels):
        pmap[(i + int(pred.index0[0]), j + int(pred.index0[1]), k + int(pred.index0[2]))] = int(v)

    def name(g, v):
        if v in (0, 254, 255):
            return None
        return canonical_name(g.class_names[v])

    occ = {"tp": 0, "fp": 0, "fn": 0}
    cls = {}
    for (i, j, k), gv in np.ndenumerate(gt.labels):
        gv = int(gv)
        if gv == 255:
            continue
        key = (i + int(gt.index0[0]), j + int(gt.index0[1]), k + int(gt.index0[2]))
        pv = pmap.get(key, 255)
        if mask == "observed" and pv == 255:
            continue
        go, po = gv not in (0, 255), pv not in (0, 255)
        occ["tp"] += go and po
        occ["fp"] += po and not go
        occ["fn"] += go and not po
        gn, pn = name(gt, gv), name(pred, pv)
        for n in {gn, pn} - {None}:
            c = cls.setdefault(n, [0, 0, 0])
            c[0] += gn == n and pn == n
            c[1] += pn == n and gn != n
            c[2] += gn == n and pn != n
    return occ, cls


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("mask", ["freeocc", "observed"])
def test_counts_match_plain_python(seed, mask):
    gt, pred = random_pair(seed)
    c = count_pair(pred, gt)[mask]
    occ, cls = brute_force(pred, gt, mask)
    assert (c.tp, c.fp, c.fn) == (occ["tp"], occ["fp"], occ["fn"])
    for n, v in cls.items():
        assert c.classes[n].tolist() == v, n
    for n, v in c.classes.items():  # classes neither side uses in the overlap count zero
        assert n in cls or v.tolist() == [0, 0, 0]


def freeocc_iou(tp, fp, fn):
    """FreeOcc's per-class IoU, percent, written out: tp / ((tp + fp + fn + 1e-5) + 1e-8)."""
    return 100.0 * tp / ((tp + fp + fn + 1e-5) + 1e-8)


def test_scores_from_counts_and_both_miou_rules():
    gt, pred = random_pair(3)
    r = evaluate([(pred, gt)], "wall,floor,chair,tv,sofa,bed")["freeocc"]
    occ, cls = brute_force(pred, gt, "freeocc")
    assert r.iou == pytest.approx(100 * occ["tp"] / (occ["tp"] + occ["fp"] + occ["fn"]))
    present = [n for n in ["wall", "floor", "chair", "tv", "sofa", "bed"] if cls.get(n, [0, 0, 0])[0] + cls.get(n, [0, 0, 0])[2] > 0]
    assert r.present == present and "sofa" not in present and "bed" not in present  # only the prediction knows sofa
    expect = np.mean([100 * cls[n][0] / sum(cls[n]) for n in present])
    assert r.miou_present == pytest.approx(expect)
    # the headline: FreeOcc's mean over all six classes of the set, sofa and bed (absent) scoring 0
    every = [freeocc_iou(*cls.get(n, [0, 0, 0])) for n in ["wall", "floor", "chair", "tv", "sofa", "bed"]]
    assert r.miou == pytest.approx(np.mean(every), rel=1e-12) and r.miou < r.miou_present
    assert r.absent == ["sofa", "bed"] and r.miou_rules_differ
    assert r.class_iou("sofa") == 0.0  # predicted but absent from GT: IoU 0
    assert math.isnan(r.class_iou("bed"))  # neither side: undefined as a ratio ...
    assert r.class_iou_freeocc("bed") == 0.0  # ... and 0 under FreeOcc's epsilon


def test_invariant_to_origin_extent_and_class_order():
    gt, pred = random_pair(4)
    base = evaluate([(pred, gt)], "all")
    # shift both grids by the same lattice offset
    g2 = grid(gt.labels, gt.index0 + [5, -7, 3], gt.class_names)
    p2 = grid(pred.labels, pred.index0 + [5, -7, 3], pred.class_names)
    # pad the GT with 255 (unscored) and the prediction with 255 (unknown) on every side
    g3 = grid(np.pad(gt.labels, 2, constant_values=255), gt.index0 - 2, gt.class_names)
    p3 = grid(np.pad(pred.labels, 3, constant_values=255), pred.index0 - 3, pred.class_names)
    # permute the prediction's class ids (same names, different order)
    perm = np.array([0, 4, 2, 5, 1, 3])
    lut = np.arange(256, dtype=np.uint8)
    lut[np.arange(1, 6)] = perm[1:]
    names = [None] * 6
    for old, new in enumerate(perm):
        names[new] = pred.class_names[old]
    p4 = grid(lut[pred.labels], pred.index0, names)
    for pp, gg in ((p2, g2), (p3, g3), (p4, gt)):
        r = evaluate([(pp, gg)], "all")
        for m in ("freeocc", "observed"):
            assert r[m].counts.tp == base[m].counts.tp and r[m].counts.fp == base[m].counts.fp
            assert r[m].counts.fn == base[m].counts.fn
            assert r[m].iou == pytest.approx(base[m].iou) and r[m].miou == pytest.approx(base[m].miou)
            assert r[m].per_class == pytest.approx(base[m].per_class, nan_ok=True)
    # cropping the prediction to the GT box changes nothing (outside the GT is dropped)
    from panovocc_cli.evaluation.align import overlap

    ov = overlap(gt, pred)
    p5 = grid(pred.labels[ov.b_slices], pred.index0 + [s.start for s in ov.b_slices], pred.class_names)
    assert evaluate([(p5, gt)], "all")["freeocc"].counts.tp == base["freeocc"].counts.tp


def test_pooling_sums_counts():
    pairs = [random_pair(s)[::-1] for s in (5, 6, 7)]
    pooled = evaluate(pairs, "eval8")["freeocc"]
    singles = [evaluate([p], "eval8")["freeocc"] for p in pairs]
    assert pooled.counts.tp == sum(s.counts.tp for s in singles)
    assert pooled.counts.fn == sum(s.counts.fn for s in singles)
    for n in ("wall", "floor", "chair"):
        assert pooled.counts.classes[n].tolist() == np.sum([s.counts.classes[n] for s in singles], axis=0).tolist()
    tp, fp, fn = (sum(getattr(s.counts, a) for s in singles) for a in ("tp", "fp", "fn"))
    assert pooled.iou == pytest.approx(100 * tp / (tp + fp + fn))


def test_edge_cases():
    gt = grid(np.array([[[1, 0], [2, 255]]]), (0, 0, 0), ["empty", "wall", "floor"])
    # empty prediction: IoU 0 (defined), every present class 0
    empty = grid(np.zeros((1, 2, 2)), (0, 0, 0), ["empty"])
    r = evaluate([(empty, gt)], "all")["freeocc"]
    assert r.iou == 0.0 and r.miou == 0.0 and r.miou_present == 0.0 and r.present == ["wall", "floor"]
    # no overlap: everything in the GT is predicted not-occupied; observed mask scores nothing
    far = grid(np.ones((2, 2, 2)), (100, 100, 100), ["empty", "wall"])
    r = evaluate([(far, gt)], "all")
    assert r["freeocc"].iou == 0.0 and r["freeocc"].counts.fn == 2
    assert r["observed"].counts.scored == 0 and math.isnan(r["observed"].iou)
    # 254 is occupied (counts for occupancy, for no class)
    occ = grid(np.array([[[254, 254], [254, 254]]]), (0, 0, 0), ["empty"])
    r = evaluate([(occ, gt)], "all")["freeocc"]
    assert (r.counts.tp, r.counts.fp, r.counts.fn) == (2, 1, 0) and r.miou == 0.0
    # a class absent from the GT counts 0 in FreeOcc's mIoU, and not at all in the present-only mean;
    # FreeOcc's 1e-5 makes a perfect one-voxel class 99.999
    r = evaluate([(gt, gt)], "wall,floor,chair")["freeocc"]
    assert r.miou_present == 100.0 and r.present == ["wall", "floor"]
    assert r.miou == pytest.approx((2 * freeocc_iou(1, 0, 0) + 0.0) / 3, rel=1e-15)
    only_absent = evaluate([(gt, gt)], "bed")["freeocc"]
    assert only_absent.miou == 0.0 and math.isnan(only_absent.miou_present)
    # observed mask drops what the prediction left unknown
    half = grid(np.array([[[1, 255], [255, 255]]]), (0, 0, 0), ["empty", "wall"])
    r = evaluate([(half, gt)], "all")
    assert r["observed"].counts.scored == 1 and r["observed"].iou == 100.0
    assert r["freeocc"].counts.scored == 3 and r["freeocc"].iou == pytest.approx(50.0)


def test_different_voxel_sizes_is_a_clear_error():
    gt, pred = random_pair(0)
    coarse = Grid(pred.labels, (pred.index0 + 0.5) * 0.1, 0.1, pred.class_names)
    with pytest.raises(PanovoccError, match="different voxel sizes"):
        evaluate([(coarse, gt)])


def test_large_pair_counts_equal_direct_numpy():
    """A 2.4-million-voxel pair (uint16 bincount keys) against direct numpy counts; speed is ``make bench``'s."""
    rng = np.random.default_rng(0)
    lab = rng.integers(0, 6, size=(150, 128, 128), dtype=np.uint8)
    gt = grid(lab, (0, 0, 0), GT_NAMES)
    pred = grid(np.roll(lab, 1, axis=0), (2, -1, 0), GT_NAMES)
    r = evaluate([(pred, gt)], "wall,floor")["freeocc"]
    p = np.zeros_like(lab)
    p[2:, :-1 or None, :] = np.roll(lab, 1, axis=0)[:-2, 1:, :]  # the prediction on the GT's voxels
    go, po = lab > 0, p > 0
    assert (r.counts.tp, r.counts.fp, r.counts.fn) == (int(np.sum(go & po)), int(np.sum(~go & po)),
                                                       int(np.sum(go & ~po)))
    assert r.counts.classes["wall"].tolist() == [int(np.sum((lab == 1) & (p == 1))), int(np.sum((lab != 1) & (p == 1))),
                                                 int(np.sum((lab == 1) & (p != 1)))]
