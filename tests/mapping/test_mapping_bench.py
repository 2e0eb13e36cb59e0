"""``panovocc bench``: update-only and whole-process figures, saved and printed."""

import json

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.mapping.bench import BenchConfig, cube_face_maps, cube_faces, run_bench


@pytest.mark.slow
def test_bench_end_to_end(tmp_path):
    res = run_bench(BenchConfig(out=str(tmp_path), frames=3, width=128, repeats=2, process_repeats=1))
    saved = json.loads((tmp_path / "bench.json").read_text())
    assert saved["line"] == res["line"] and "semantic update" in saved["line"] and "whole process" in saved["line"]
    for k in ("geometry", "semantics", "segmenter", "open3d"):
        assert len(saved["update_passes_ms"][k]) == 2 and saved["update_ms_per_frame"][k] > 0
    for k in ("map_semantics", "map_geometry", "open3d"):
        assert len(saved["process_runs_s"][k]) == 1 and saved["process_seconds"][k] > 0
    ms, sec = saved["update_ms_per_frame"], saved["process_seconds"]
    assert saved["ratio_semantic_to_geometric_update"] == pytest.approx(ms["semantics"] / ms["geometry"])
    assert saved["ratio_map_with_semantics_to_open3d_process"] == pytest.approx(sec["map_semantics"] / sec["open3d"])
    with pytest.raises(PanovoccError):
        run_bench(BenchConfig(out=str(tmp_path), frames=1, width=128))


def test_cube_faces_cover_the_panorama():
    """Every face pixel samples the ERP image; a constant radial depth r gives z = r / |ray|."""
    maps = cube_face_maps(64, 128, 32)
    faces, K = cube_faces(np.full((64, 128), 2.0, np.float32), 32, maps)
    assert len(faces) == 6 and K[0, 0] == 16
    for R, z in faces:
        assert z.shape == (32, 32) and np.all(z <= 2.0) and np.all(z >= 2.0 / np.sqrt(3) - 1e-6)
    seen = np.zeros((64, 128), bool)
    seen[maps[1], maps[2]] = True
    assert seen.mean() > 0.5
