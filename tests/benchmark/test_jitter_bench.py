"""make bench-jitter's table (benchmark/jitter.py): losses against the true-pose map of the same spill, and a
jitter list that does not start with the true poses is refused."""

import pytest

from panovocc_cli.benchmark.jitter import main, markdown


def test_markdown_rows_give_the_loss_against_the_same_spill():
    jitters = ((0.0, 0.0), (0.01, 0.1))
    rows = [{"scene": "home2", "depth": "clean", "sigma_t_mm": 0.0, "sigma_r_deg": 0.0, "spill": 0.0, "iou": 81.37, "loss": 0.0},
            {"scene": "home2", "depth": "clean", "sigma_t_mm": 0.0, "sigma_r_deg": 0.0, "spill": 0.3, "iou": 81.14, "loss": 0.0},
            {"scene": "home2", "depth": "clean", "sigma_t_mm": 10.0, "sigma_r_deg": 0.1, "spill": 0.0, "iou": 64.84, "loss": 16.53},
            {"scene": "home2", "depth": "clean", "sigma_t_mm": 10.0, "sigma_r_deg": 0.1, "spill": 0.3, "iou": 81.5, "loss": -0.36}]
    md = markdown(rows, jitters).splitlines()
    assert md[0] == "| scene | depth | spill | 0 mm / 0° | 10 mm / 0.1° |"
    assert md[2] == "| home2 | clean | 0 | 81.37 | 64.84 (−16.53) |"
    assert md[3] == "| home2 | clean | 0.3 | 81.14 | 81.50 (+0.36) |"


def test_jitters_must_start_with_the_true_poses(tmp_path):
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "w"), "--jitters", "0.01:0.1,0:0"])
    assert e.value.code == 2 and not (tmp_path / "w").exists()
