"""ReplicaOcc .pkl conversion, score tables and pictures."""

import io
import pickle

import numpy as np
import pytest

from panovocc_cli.classes import class_color
from panovocc_cli.errors import PanovoccError
from panovocc_cli.evaluation.metrics import evaluate
from panovocc_cli.evaluation.render_grid import drawing_box, render_voxels
from panovocc_cli.evaluation.replicaocc import SafeUnpickler, read_replicaocc, write_replicaocc
from panovocc_cli.evaluation.show import render_panels, save_panels
from panovocc_cli.evaluation.tables import to_csv, to_latex, to_markdown, write_tables
from panovocc_cli.grid import Grid


def replicaocc_dict(h=0.08):
    """A small ReplicaOcc-style dict: a 4x3x2 scene listed as centres, ids 1..3 into the user's names."""
    rng = np.random.default_rng(0)
    ijk = np.stack(np.meshgrid(np.arange(4), np.arange(3), np.arange(2), indexing="ij"), -1).reshape(-1, 3)
    i0 = np.array([-12, 5, -1])
    labels = rng.choice([0, 1, 2, 3, 255], size=len(ijk))
    return {"global_labels": labels.tolist(), "global_pts": ((ijk + i0 + 0.5) * h).tolist(), "scene_dim": [4, 3, 2]}, \
        ijk, labels


def test_replicaocc_reads_lists_and_round_trips(tmp_path):
    d, ijk, labels = replicaocc_dict()
    with open(tmp_path / "scene.pkl", "wb") as f:
        pickle.dump(d, f)
    g, shift = read_replicaocc(tmp_path / "scene.pkl", ["wall", "floor", "tv-screen"])
    assert g.class_names == ["empty", "wall", "floor", "tv"] and not shift.any()
    assert g.labels.shape == (4, 3, 2) and np.allclose(g.origin, (np.array([-12, 5, -1]) + 0.5) * 0.08)
    assert np.array_equal(g.labels[tuple(ijk.T)], labels)
    # the same ids with the list naming id 0 first
    g0, _ = read_replicaocc(tmp_path / "scene.pkl", ["free", "wall", "floor", "tv-screen"])
    assert np.array_equal(g0.labels, g.labels) and g0.class_names == g.class_names
    write_replicaocc(tmp_path / "back.pkl", g)
    write_replicaocc(tmp_path / "back2.pkl", g)
    assert (tmp_path / "back.pkl").read_bytes() == (tmp_path / "back2.pkl").read_bytes()
    g2, _ = read_replicaocc(tmp_path / "back.pkl", None)  # names travel in the file we wrote
    assert np.array_equal(g2.labels, g.labels) and g2.class_names == g.class_names
    assert np.allclose(g2.origin, g.origin) and g2.voxel_size == g.voxel_size
    r = evaluate([(g2, g)], "all")["freeocc"]
    assert r.iou == 100.0 and r.miou == 100.0


def test_replicaocc_rejects_bad_input(tmp_path):
    d, _, _ = replicaocc_dict()
    off = dict(d, global_pts=(np.asarray(d["global_pts"]) + 0.03).tolist())
    cases = {
        "off.pkl": (off, "off the global lattice"),
        "ids.pkl": (d, "has no class name"),
        "keys.pkl": ({"global_labels": [1]}, "missing keys"),
        "dim.pkl": (dict(d, scene_dim=[2, 2, 2]), "scene_dim"),
    }
    for name, (data, msg) in cases.items():
        with open(tmp_path / name, "wb") as f:
            pickle.dump(data, f)
        names = ["wall"] if name == "ids.pkl" else ["wall", "floor", "tv"]
        with pytest.raises(PanovoccError, match=msg):
            read_replicaocc(tmp_path / name, names)
    g, shift = read_replicaocc(tmp_path / "off.pkl", ["wall", "floor", "tv"], allow_shift=True)
    assert np.allclose(shift, -0.03)

    class Evil:
        def __reduce__(self):
            return (print, ("this must not run",))

    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        SafeUnpickler(io.BytesIO(pickle.dumps({"global_labels": Evil()}))).load()


def test_tables_text():
    g = Grid(np.array([[[1, 2], [0, 0]]], np.uint8), np.full(3, 0.04), 0.08, ["empty", "wall", "floor"])
    p = Grid(np.array([[[1, 1], [0, 0]]], np.uint8), np.full(3, 0.04), 0.08, ["empty", "wall"])
    res = evaluate([(p, g)], "wall,floor,bed")
    rows = [res["freeocc"], res["observed"]]
    csv = to_csv(rows, ["ours", "ours"]).splitlines()
    assert csv[0] == "name,mask,IoU,mIoU,wall,floor,bed"
    assert csv[1] == "ours,freeocc,100.00,25.00,50.00,0.00,-"
    assert "| ours | freeocc | 100.00 | 25.00 |" in to_markdown(rows, ["ours", "ours"])
    assert r"\toprule" in to_latex(rows, ["ours", "ours"])


def box_grid():
    lab = np.zeros((12, 10, 8), np.uint8)
    lab[:, :, 0] = 2  # floor
    lab[0, :, :] = lab[:, 0, :] = 1  # wall
    lab[4:7, 4:7, 1:4] = 3  # chair
    lab[:, :, -1] = 4  # ceiling
    return Grid(lab, np.full(3, 0.04), 0.08, ["empty", "wall", "floor", "chair", "ceiling"])


def test_render_palette_cut_top_and_determinism(tmp_path):
    g = box_grid()
    lo, hi, z_keep = drawing_box([g], cut_top=1)
    assert z_keep == 6 and hi[2] == 6
    img, drawn = render_voxels(g, lo, hi, 3)
    assert img.shape == (3 * (12 + 10 + 7), 3 * (12 + 10), 3) and drawn.any()
    colours = {tuple(c) for c in img[drawn].reshape(-1, 3)}
    for name in ("wall", "floor", "chair"):
        assert tuple(class_color(name)) in colours, name  # top faces carry the exact palette colour
    assert tuple(class_color("ceiling")) not in colours  # cut away
    images, legend = render_panels([g, g], cut_top=1, panel_px=200)
    assert legend == ["floor", "wall", "chair"]
    a = save_panels(images, legend, tmp_path / "a.png", ["prediction", "ground truth"], width_px=640)
    save_panels(images, legend, tmp_path / "b.png", ["prediction", "ground truth"], width_px=640)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    import matplotlib.image as mpimg

    png = mpimg.imread(tmp_path / "a.png")
    assert png.shape[:2] == a and png.shape[1] == 640
    with pytest.raises(PanovoccError, match="removes every"):
        render_panels([g], cut_top=8)


def test_write_tables_files(tmp_path):
    g = box_grid()
    res = evaluate([(g, g)], "eval8")
    paths = write_tables([res["freeocc"]], ["gt"], tmp_path / "t")
    assert [p.name for p in paths] == ["scores.csv", "scores.md", "scores.tex"]
    assert all(p.is_file() for p in paths)
