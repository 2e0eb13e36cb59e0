"""io/runconfig.py: where a stage's config.json goes and that the same config gives the same bytes."""

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panovocc_cli.io.runconfig import config_json, config_path_beside, write_run_config


@dataclass
class _Cfg:
    out: Path
    size: float = 0.08
    pair: tuple = (Path("a.npz"), Path("b.npz"))
    nested: dict = field(default_factory=lambda: {"n": np.int64(3), "v": np.arange(2), "x": float("nan")})
    progress: bool = True


def test_config_json_is_plain_deterministic_and_drops_runtime_fields(tmp_path):
    cfg = _Cfg(tmp_path / "o")
    text = config_json(cfg)
    assert text == config_json(_Cfg(tmp_path / "o")) and text.endswith("}\n")
    d = json.loads(text)
    assert list(d) == ["out", "size", "pair", "nested"]  # declaration order, progress left out
    assert d["out"] == str(tmp_path / "o") and d["pair"] == ["a.npz", "b.npz"]
    assert d["nested"] == {"n": 3, "v": [0, 1], "x": None}
    p = write_run_config(tmp_path / "config.json", cfg)
    assert p.read_text() == text


def test_one_file_outputs_get_a_config_beside_them():
    assert config_path_beside(Path("w/gt.npz")) == Path("w/gt.config.json")
    assert config_path_beside(Path("w/compare.png")) == Path("w/compare.config.json")
    assert config_path_beside(Path("w/grid")) == Path("w/grid.config.json")
