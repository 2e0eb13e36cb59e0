"""End to end: panovocc eval / coverage / show / convert, and one-line errors with exit status 2."""

import json
import pickle

import numpy as np
import pytest

from panovocc_cli.cli import main
from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import read_grid, write_grid
from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses

from test_eval_coverage import box_depth, box_room_gt, trajectory


def run(capsys, *args):
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    out = capsys.readouterr()
    return e.value.code, out.out, out.err


@pytest.fixture()
def pair(tmp_path):
    gt = box_room_gt()
    lab = gt.labels.copy()
    lab[1:-1, 1:-1, 0] = 2  # the floor layer becomes class 'floor'
    gt = Grid(lab, gt.origin, gt.voxel_size, ["empty", "wall", "floor"])
    pred_lab = lab[2:, :, :].copy()  # the prediction misses the -x wall and calls the floor 'wall'
    pred_lab[pred_lab == 2] = 1
    pred = Grid(pred_lab, gt.origin + [2 * 0.08, 0, 0], 0.08, ["empty", "wall"])
    write_grid(tmp_path / "gt.npz", gt)
    write_grid(tmp_path / "pred.npz", pred)
    return tmp_path / "pred.npz", tmp_path / "gt.npz"


def test_eval_table_json_out_and_pooling(capsys, tmp_path, pair):
    pred, gt = pair
    code, out, _ = run(capsys, "eval", pred, gt, "--out", tmp_path / "scores")
    assert code == 0 and "FreeOcc (headline)" in out and "observed only" in out and "absent from GT" in out
    for f in ("scores.csv", "scores.md", "scores.tex", "counts.csv", "scores.json", "config.json"):
        assert (tmp_path / "scores" / f).is_file(), f
    code, out, _ = run(capsys, "eval", pred, gt, "--json", "--classes", "wall,floor")
    single = json.loads(out)
    assert code == 0 and single["mask"] == "freeocc" and single["classes"] == ["wall", "floor"]
    assert single["per_class"]["floor"] == 0.0 and 0 < single["iou"] < 100
    assert set(single["masks"]) == {"freeocc", "observed"}
    (tmp_path / "pairs.csv").write_text(f"pred,gt\n{pred.name},{gt.name}\n# comment\n")
    code, out, _ = run(capsys, "eval", pred, gt, "--pair", pred, gt, "--pairs", tmp_path / "pairs.csv", "--json",
                       "--classes", "wall,floor", "--mask", "observed")
    pooled = json.loads(out)
    assert pooled["mask"] == "observed" and pooled["counts"]["pairs"] == 3 and len(pooled["pairs"]) == 3
    assert pooled["masks"]["freeocc"]["counts"]["tp"] == 3 * single["counts"]["tp"]
    assert pooled["masks"]["freeocc"]["iou"] == pytest.approx(single["iou"])


def test_eval_bad_inputs_exit_2(capsys, tmp_path, pair):
    pred, gt = pair
    coarse = read_grid(gt)
    write_grid(tmp_path / "coarse.npz", Grid(coarse.labels, np.full(3, 0.05), 0.1, coarse.class_names))
    for args in ([pred, tmp_path / "missing.npz"], [pred], [pred, tmp_path / "coarse.npz"],
                 [pred, gt, "--mask", "nope"], [pred, gt, "--pair", pred], [pred, gt, "--classes", " , "],
                 [pred, gt, "--classes", ""]):
        code, out, err = run(capsys, "eval", *args)
        assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, (args, err)


def write_box_sequence(root, width=128):
    poses = trajectory()
    write_meta(root, SequenceMeta(width=width, height=width // 2, frames=len(poses)))
    write_sequence_poses(root, np.stack(poses))
    for i, T in enumerate(poses):
        write_frame(root, i, np.zeros((width // 2, width, 3), np.uint8), box_depth(T, width), None)


def test_coverage_command(capsys, tmp_path):
    write_box_sequence(tmp_path / "seq", 256)
    write_grid(tmp_path / "gt.npz", box_room_gt())
    code, out, err = run(capsys, "coverage", tmp_path / "seq", tmp_path / "gt.npz", "--out", tmp_path / "cov",
                         "--every", "2")
    assert code == 0, err
    rows = (tmp_path / "cov" / "coverage.csv").read_text().splitlines()
    assert rows[0] == "frame,panoramic,perspective" and [r.split(",")[0] for r in rows[1:]] == ["0", "2", "3"]
    vals = np.array([[float(x) for x in r.split(",")[1:]] for r in rows[1:]])
    assert vals[0, 0] == pytest.approx(1.0) and np.all(vals[:, 0] >= vals[:, 1])
    assert (tmp_path / "cov" / "coverage.png").stat().st_size > 1000
    assert "100.00%" in out
    code, _, err = run(capsys, "coverage", tmp_path / "seq", tmp_path / "gt.npz", "--out", tmp_path / "c2",
                       "--fov-deg", "200")
    assert code == 2 and err.startswith("error: ")


def test_show_and_convert_commands(capsys, tmp_path, pair):
    pred, gt = pair
    code, out, err = run(capsys, "show", pred, gt, tmp_path / "pic.png", "--cut-top", "1", "--titles",
                         "prediction,ground truth", "--width-px", "800")
    assert code == 0, err
    import matplotlib.image as mpimg

    assert mpimg.imread(tmp_path / "pic.png").shape[1] == 800
    code, _, err = run(capsys, "show", pred, gt, tmp_path / "pic.png", "--titles", "only one", "--overwrite")
    assert code == 2 and "titles" in err

    code, out, err = run(capsys, "convert", "to-replicaocc", gt, tmp_path / "gt.pkl")
    assert code == 0 and "replica ids" in out, err
    with open(tmp_path / "gt.pkl", "rb") as f:
        d = pickle.load(f)
    a = read_grid(gt)
    assert set(d) >= {"global_labels", "global_pts", "scene_dim", "global_mask"}
    assert d["global_labels"].shape == a.labels.shape and d["global_pts"].shape == a.labels.shape + (3,)
    # FreeOcc's ids: 1 + the line of replica_name.txt (wall is line 92, floor line 39, 0-based)
    assert set(np.unique(d["global_labels"])) <= {0, 40, 93, 255}
    code, out, err = run(capsys, "convert", "replicaocc", tmp_path / "gt.pkl", tmp_path / "back.npz")
    assert code == 0 and "from the file" in out, err
    b = read_grid(tmp_path / "back.npz")
    names_a = np.array(a.class_names + [""] * 256)[:256]
    names_b = np.array(b.class_names + [""] * 256)[:256]
    assert np.array_equal(names_a[a.labels], names_b[b.labels]) and np.array_equal(a.origin, b.origin)
    # the grid's own ids, named by a file
    code, _, err = run(capsys, "convert", "to-replicaocc", gt, tmp_path / "own.pkl", "--ids", "own")
    assert code == 0, err
    (tmp_path / "names.txt").write_text("# ids 1..\nwall\nfloor\n")
    code, out, err = run(capsys, "convert", "replicaocc", tmp_path / "own.pkl", tmp_path / "back2.npz",
                         "--class-names", tmp_path / "names.txt")
    assert code == 0, err
    b = read_grid(tmp_path / "back2.npz")
    assert np.array_equal(a.labels, b.labels) and a.class_names == b.class_names
    code, _, err = run(capsys, "convert", "replicaocc", tmp_path / "own.pkl", tmp_path / "x.npz", "--class-names",
                       "wall", "--voxel-size", "0.1")
    assert code == 2 and "voxel_size" in err and not (tmp_path / "x.npz").exists()


def snapshot(root):
    """Every path under root with its bytes (files) or None (folders)."""
    return {p: (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def test_bad_outputs_and_inputs_one_line_exit_2_nothing_changed(capsys, tmp_path, pair):
    pred, gt = pair
    write_box_sequence(tmp_path / "seq", 64)
    (tmp_path / "afile").write_text("keep me\n")
    (tmp_path / "adir").mkdir()
    (tmp_path / "binary.csv").write_bytes(bytes(range(256)) * 4)
    (tmp_path / "nul.csv").write_text("pred.npz,gt.npz\x00\n")
    with open(tmp_path / "abc.pkl", "wb") as f:
        pickle.dump({"global_labels": np.zeros((2, 2, 2), np.uint8), "global_pts": np.zeros((2, 2, 2, 3)),
                     "voxel_size": "abc"}, f)
    (tmp_path / "truncated.pkl").write_bytes(pickle.dumps({"global_labels": np.zeros(1000)}, protocol=4)[:300])
    with open(tmp_path / "list.pkl", "wb") as f:
        pickle.dump([1, 2, 3], f)
    code, _, err = run(capsys, "convert", "to-replicaocc", gt, tmp_path / "good.pkl")
    assert code == 0, err
    f, d = tmp_path / "afile", tmp_path / "adir"
    cases = [
        ["eval", pred, gt, "--out", f / "sub"],  # under an existing file
        ["eval", pred, gt, "--out", f],  # a file where a folder is expected
        ["eval", "--pairs", tmp_path / "binary.csv"],
        ["eval", "--pairs", tmp_path / "nul.csv"],
        ["eval", "--pairs", d],
        ["coverage", tmp_path / "seq", gt, "--out", f / "cov"],
        ["coverage", tmp_path / "seq", gt, "--out", f],
        ["convert", "to-replicaocc", gt, f / "x.pkl"],
        ["convert", "to-replicaocc", gt, d],  # a folder where a file is expected
        ["convert", "to-replicaocc", gt, gt],  # over its own input
        ["convert", "to-replicaocc", gt, tmp_path / "x.pkl", "--ids", "nope"],
        ["convert", "replicaocc", tmp_path / "good.pkl", f / "x.npz"],
        ["convert", "replicaocc", tmp_path / "good.pkl", d],
        ["convert", "replicaocc", tmp_path / "abc.pkl", tmp_path / "x.npz"],
        ["convert", "replicaocc", tmp_path / "truncated.pkl", tmp_path / "x.npz"],
        ["convert", "replicaocc", tmp_path / "list.pkl", tmp_path / "x.npz"],
        ["convert", "replicaocc", tmp_path / "binary.csv", tmp_path / "x.npz"],
        ["show", pred, gt, f / "x.png"],
    ]
    before = snapshot(tmp_path)
    for args in cases:
        code, out, err = run(capsys, *args)
        assert code == 2 and err.startswith("error: ") and len(err.strip().splitlines()) == 1, (args, err)
        assert "Traceback" not in err
    assert snapshot(tmp_path) == before


def test_failed_eval_and_coverage_leave_no_folder(capsys, tmp_path, pair, monkeypatch):
    pred, gt = pair
    # failing before anything is written: no folder
    code, _, err = run(capsys, "eval", pred, tmp_path / "missing.npz", "--out", tmp_path / "e1" / "nested")
    assert code == 2 and not (tmp_path / "e1").exists()
    # failing while writing (a full disk): the folders this run created are removed, one line, exit 2
    import errno

    import panovocc_cli.evaluation.run as run_mod

    def disk_full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(run_mod, "write_csv", disk_full)
    code, _, err = run(capsys, "eval", pred, gt, "--out", tmp_path / "e2" / "nested")
    assert code == 2 and "No space left" in err and not (tmp_path / "e2").exists()
    # an existing output folder is kept (and only the files written atomically are new)
    (tmp_path / "e3").mkdir()
    code, _, err = run(capsys, "eval", pred, gt, "--out", tmp_path / "e3")
    assert code == 2 and (tmp_path / "e3").is_dir()
    monkeypatch.undo()
    write_box_sequence(tmp_path / "seq", 64)
    import panovocc_cli.evaluation.show as show_mod

    monkeypatch.setattr(show_mod, "coverage_figure", disk_full)
    code, _, err = run(capsys, "coverage", tmp_path / "seq", gt, "--out", tmp_path / "c1")
    assert code == 2 and "No space left" in err and not (tmp_path / "c1").exists()
    monkeypatch.undo()
    code, _, err = run(capsys, "coverage", tmp_path / "seq", tmp_path / "missing.npz", "--out", tmp_path / "c2")
    assert code == 2 and not (tmp_path / "c2").exists()


def test_eval_prints_both_miou_rules_when_a_class_is_absent(capsys, pair):
    pred, gt = pair  # the ground truth has wall and floor only: six eval8 classes are absent
    code, out, _ = run(capsys, "eval", pred, gt)
    assert code == 0 and "mIoU (present only)" in out and "absent from GT (0)" in out
    code, out, _ = run(capsys, "eval", pred, gt, "--json")
    r = json.loads(out)
    assert r["absent"] == ["ceiling", "window", "chair", "bed", "sofa", "table"]
    assert r["miou"] == pytest.approx(sum(r["per_class_freeocc"].values()) / 8)
    assert r["miou_present"] == pytest.approx((r["per_class"]["wall"] + r["per_class"]["floor"]) / 2)
    code, out, _ = run(capsys, "eval", pred, gt, "--classes", "wall,floor")  # nothing absent: one mIoU line
    assert code == 0 and "present only" not in out


def test_eval_refuses_a_ground_truth_with_no_occupied_voxel(capsys, tmp_path, pair):
    """A ground truth whose labels are all 0 (or 0 and 255) has nothing to score: refused on one line naming
    it, as coverage refuses it, instead of an IoU of 0 from false positives alone."""
    pred, gt = pair
    g = read_grid(gt)
    for name, fill in (("zeros.npz", 0), ("free_unknown.npz", 255)):
        lab = np.zeros_like(g.labels)
        lab[0] = fill
        write_grid(tmp_path / name, Grid(lab, g.origin, g.voxel_size, g.class_names))
        code, out, err = run(capsys, "eval", pred, tmp_path / name)
        assert code == 2 and name in err and "no occupied voxel" in err and len(err.strip().splitlines()) == 1, err
        assert out == ""
