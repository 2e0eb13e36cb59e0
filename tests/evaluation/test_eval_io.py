"""Score tables and pictures."""

import numpy as np
import pytest

from panovocc_cli.classes import class_color
from panovocc_cli.errors import PanovoccError
from panovocc_cli.evaluation.metrics import evaluate
from panovocc_cli.evaluation.render_grid import drawing_box, render_voxels
from panovocc_cli.evaluation.show import panels_figure, render_panels
from panovocc_cli.io.figures import write_png
from panovocc_cli.evaluation.run import write_score_tables
from panovocc_cli.evaluation.tables import counts_rows, table_rows
from panovocc_cli.io.tables import csv_text, latex_text, markdown_text
from panovocc_cli.grid import Grid


def test_tables_text():
    g = Grid(np.array([[[1, 2], [0, 0]]], np.uint8), np.full(3, 0.04), 0.08, ["empty", "wall", "floor"])
    p = Grid(np.array([[[1, 1], [0, 0]]], np.uint8), np.full(3, 0.04), 0.08, ["empty", "wall"])
    res = evaluate([(p, g)], "wall,floor,bed")
    header, rows = table_rows([res["freeocc"], res["observed"]], ["ours", "ours"])
    csv = csv_text(header, rows).splitlines()
    assert csv[0] == "name,mask,IoU,mIoU,mIoU_present,wall,floor,bed"
    # FreeOcc's mIoU averages all three classes (bed, absent from the GT, scores 0): (50 + 0 + 0) / 3
    assert csv[1] == "ours,freeocc,100.00,16.67,25.00,50.00,0.00,-"
    assert "| ours | freeocc | 100.00 | 16.67 | 25.00 |" in markdown_text(header, rows)
    assert r"\toprule" in latex_text(header, rows) and r"mIoU\_present" in latex_text(header, rows)
    ch, cr = counts_rows([res["freeocc"]], ["ours"])
    assert ch[:3] == ["name", "mask", "class"] and cr[0] == ["ours", "freeocc", "occupancy", 2, 0, 0, 2]


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
    fig, a = panels_figure(images, legend, ["prediction", "ground truth"], width_px=640)
    write_png(fig, tmp_path / "a.png")
    write_png(panels_figure(images, legend, ["prediction", "ground truth"], width_px=640)[0], tmp_path / "b.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    import matplotlib.image as mpimg

    png = mpimg.imread(tmp_path / "a.png")
    assert png.shape[:2] == a and png.shape[1] == 640
    with pytest.raises(PanovoccError, match="removes every"):
        render_panels([g], cut_top=8)


def test_write_tables_files(tmp_path):
    g = box_grid()
    res = evaluate([(g, g)], "eval8")
    paths = write_score_tables([res["freeocc"]], ["gt"], tmp_path / "t")
    assert [p.name for p in paths] == ["scores.csv", "scores.md", "scores.tex"]
    assert all(p.is_file() for p in paths)


def test_floor_plans_two_storeys_closed_form(tmp_path):
    """Two floors (layers 0 and 5) of a 6 x 4 grid: a wall column on each, a chair on the upper one; the plan
    shows per column the highest thing above the floor, else the floor, white where there is no floor (the
    upper floor's stairwell); the walk is split between the panels by height."""
    from panovocc_cli.evaluation.show import floor_layers, floor_plans_figure, plan_image

    names = ["empty", "floor", "wall", "chair"]
    lab = np.zeros((6, 4, 10), np.uint8)
    lab[:, :, 0] = 1
    lab[:, :, 5] = 1
    lab[4:, :, 5] = 0  # a hole in the upper floor
    lab[0, :, 1:5] = 2  # a wall on the ground floor
    lab[0, :, 6:10] = 2
    lab[2, 1, 6] = 3  # a chair upstairs
    g = Grid(lab, np.array([0.04, 0.04, 0.04]), 0.08, names)
    assert floor_layers(g) == [0, 5]
    low, up = plan_image(g, 0, height_m=0.3), plan_image(g, 5, height_m=0.3)
    assert low.shape == up.shape == (4, 6, 3)  # rows = y, columns = x
    assert tuple(low[0, 0]) == class_color("wall") and tuple(low[2, 3]) == class_color("floor")
    assert tuple(up[1, 2]) == class_color("chair") and tuple(up[0, 5]) == (255, 255, 255)
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, 2, 3] = [0.2, 0.2, 0.6, 0.62]  # two poses on each floor (eye_min_m = 0.15 above its bottom face)
    T[:, 0, 3] = [0.1, 0.2, 0.3, 0.4]
    fig = floor_plans_figure(g, T, width_px=400, eye_min_m=0.15)
    titles = sorted(ax.get_title(loc="left") for ax in fig.axes if ax.get_title(loc="left"))
    assert titles[0].startswith("floor 0") and "frames 0-1" in titles[0] and "frames 2-3" in titles[1]
    write_png(fig, tmp_path / "plans.png")
    assert (tmp_path / "plans.png").stat().st_size > 0
