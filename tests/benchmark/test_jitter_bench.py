"""make bench-jitter's table (benchmark/jitter.py): losses against the true-pose map of the same export (spill
thinning, face resolution), and a jitter list that does not start with the true poses is refused."""

import pytest

from panovocc_cli.benchmark.jitter import grid_figure, grid_markdown, main, markdown


def test_markdown_rows_give_the_loss_against_the_same_export():
    jitters = ((0.0, 0.0), (0.01, 0.1))
    row = (lambda t, r, k, res, iou, loss: {"scene": "home2", "depth": "clean", "sigma_t_mm": t, "sigma_r_deg": r,  # noqa: E731
                                            "spill": k, "resolve": res, "iou": iou, "loss": loss})
    rows = [row(0.0, 0.0, 0.0, 0, 81.37, 0.0), row(0.0, 0.0, 0.3, 0, 81.14, 0.0), row(0.0, 0.0, 0.0, 1, 81.2, 0.0),
            row(10.0, 0.1, 0.0, 0, 64.84, 16.53), row(10.0, 0.1, 0.3, 0, 81.5, -0.36), row(10.0, 0.1, 0.0, 1, 80.0, 1.2)]
    md = markdown(rows, jitters).splitlines()
    assert md[0] == "| scene | depth | spill | resolve | 0 mm / 0° | 10 mm / 0.1° |"
    assert md[2] == "| home2 | clean | 0 | off | 81.37 | 64.84 (−16.53) |"
    assert md[3] == "| home2 | clean | 0.3 | off | 81.14 | 81.50 (+0.36) |"
    assert md[4] == "| home2 | clean | 0 | on | 81.20 | 80.00 (−1.20) |"


def test_jitters_must_start_with_the_true_poses(tmp_path):
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "w"), "--jitters", "0.01:0.1,0:0"])
    assert e.value.code == 2 and not (tmp_path / "w").exists()


def test_grid_markdown_puts_translation_in_rows_and_rotation_in_columns():
    row = (lambda t, r, iou, loss: {"scene": "home3", "depth": "realistic", "sigma_t_mm": t, "sigma_r_deg": r,  # noqa: E731
                                    "spill": 0.0, "resolve": 0, "iou": iou, "loss": loss})
    rows = [row(0.0, 0.0, 73.6, 0.0), row(0.0, 0.1, 72.0, 1.6), row(10.0, 0.0, 71.5, 2.1), row(10.0, 0.1, 71.16, 2.44)]
    md = grid_markdown(rows, (0.0, 0.01), (0.0, 0.1)).splitlines()
    assert md[0] == "home3, realistic depth, spill 0, resolve off:"
    assert md[2] == "| σ_t \\ σ_r | 0° | 0.1° |"
    assert md[4] == "| 0 mm | 73.60 | 72.00 (−1.60) |"
    assert md[5] == "| 10 mm | 71.50 (−2.10) | 71.16 (−2.44) |"


@pytest.mark.parametrize("grid", ["0.01,0.02:0,0.1", "0,0.01:0.1", "0,0.01", "0,x:0,0.1"])
def test_a_grid_without_the_true_poses_or_malformed_is_refused(tmp_path, grid):
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "w"), "--grid", grid])
    assert e.value.code == 2 and not (tmp_path / "w").exists()


def test_grid_figure_draws_one_heat_map_per_scene_and_export_with_the_losses():
    rows = [{"scene": s, "depth": "clean", "sigma_t_mm": t, "sigma_r_deg": r, "spill": 0.0, "resolve": 0,
             "iou": 80.0, "loss": 0.0 if not (t or r) else 1.0 + t + 10 * r}
            for s in ("home2", "home3") for t in (0.0, 10.0) for r in (0.0, 0.1)]
    fig = grid_figure(rows, (0.0, 0.01), (0.0, 0.1))
    maps = [ax for ax in fig.axes if ax.images]
    assert len(maps) == 2 and [ax.get_title() for ax in maps] == ["home2, clean", "home3, clean"]
    assert [t.get_text() for t in maps[0].texts] == ["0.0", "2.0", "11.0", "12.0"]
