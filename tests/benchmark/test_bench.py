"""``panovocc bench``: update-only and whole-process figures, saved and printed."""

import json

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.benchmark.bench import BenchConfig, cube_faces, cube_sampler, run_bench


@pytest.mark.slow
def test_bench_end_to_end(tmp_path):
    res = run_bench(BenchConfig(out=str(tmp_path), frames=3, width=128, repeats=2, process_repeats=2))
    saved = json.loads((tmp_path / "bench.json").read_text())
    assert saved["line"] == res["line"] and "semantic update" in saved["line"] and "whole process" in saved["line"]
    for k in ("geometry", "semantics", "segmenter", "open3d"):
        assert len(saved["update_passes_ms"][k]) == 2 and saved["update_ms_per_frame"][k] > 0
    for k in ("map_semantics", "map_geometry", "open3d"):
        runs = saved["process_runs_s"][k]
        assert len(runs) == 2 and saved["process_seconds"][k] == pytest.approx(np.median(runs))
        assert saved["process_best_s"][k] == min(runs) > 0
    ms, sec = saved["update_ms_per_frame"], saved["process_seconds"]
    assert saved["ratio_semantic_to_geometric_update"] == pytest.approx(ms["semantics"] / ms["geometry"])
    assert saved["ratio_map_with_semantics_to_open3d_process"] == pytest.approx(sec["map_semantics"] / sec["open3d"])
    best = saved["process_best_s"]
    assert saved["ratio_map_with_semantics_to_open3d_process_best"] == pytest.approx(best["map_semantics"] / best["open3d"])
    assert saved["ratio_map_without_semantics_to_open3d_process_best"] == pytest.approx(best["map_geometry"] / best["open3d"])
    assert "fastest runs" in saved["line"]
    with pytest.raises(PanovoccError):
        run_bench(BenchConfig(out=str(tmp_path), frames=1, width=128))


def test_cube_faces_cover_the_panorama():
    """Every face pixel samples the ERP image; a constant radial depth r gives z = r / |ray|; the faces look
    along +z, +x, -z, -x, up (-y) and down (+y) of the panorama."""
    sampler = cube_sampler(128)
    faces, K = cube_faces(np.full((64, 128), 2.0, np.float32), sampler)
    assert len(faces) == 6 and K[0, 0] == pytest.approx(16) and K[0, 2] == 15.5
    for R, z in faces:
        assert z.dtype == np.float32 and z.shape == (32, 32)
        assert np.all(z <= 2.0) and np.all(z >= 2.0 / np.sqrt(3) - 1e-6)
        assert np.allclose(R.T @ R, np.eye(3))
    axes = np.array([R[:, 2] for R, _ in faces])
    assert np.array_equal(axes, [[0, 0, 1], [1, 0, 0], [0, 0, -1], [-1, 0, 0], [0, -1, 0], [0, 1, 0]])
    seen = np.zeros((64, 128), bool)
    seen[sampler.row, sampler.col] = True
    assert seen.mean() > 0.5
