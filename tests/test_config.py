"""Option ranges declared once (config.option) and enforced everywhere by config.validate_config: the
command line and the Python API (every ``run_*``) refuse the same values with the same one-line message;
run_* check their outputs as the command line does."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from panovocc_cli.config import OPT_KEY, validate_config
from panovocc_cli.errors import PanovoccError


def _configs():
    from panovocc_cli.baselines.views import ViewsConfig
    from panovocc_cli.datasets.synth import SynthConfig
    from panovocc_cli.demo import DemoConfig
    from panovocc_cli.evaluation.run import (ConvertReplicaOccConfig, ConvertToReplicaOccConfig, CoverageConfig,
                                             EvalConfig, SegevalConfig, ShowConfig)
    from panovocc_cli.gt_config import GtConfig
    from panovocc_cli.benchmark.bench import BenchConfig
    from panovocc_cli.mapping.config import MapConfig, ReviseConfig
    from panovocc_cli.rendering.render import RenderConfig

    return [SynthConfig, DemoConfig, ConvertReplicaOccConfig, ConvertToReplicaOccConfig, CoverageConfig, EvalConfig,
            ShowConfig, GtConfig, BenchConfig, MapConfig, ReviseConfig, SegevalConfig, RenderConfig, ViewsConfig]


def _with_required(cls, **kw):
    """An instance with every field that has no default set to a placeholder path."""
    need = {f.name: Path("x") for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    need.update(kw)
    return cls(**need)


@pytest.mark.parametrize("cls", _configs(), ids=lambda c: c.__name__)
def test_defaults_are_valid_and_every_command_declares_its_options(cls):
    cfg = _with_required(cls)
    assert validate_config(cfg) == cfg
    assert any(OPT_KEY in f.metadata for f in dataclasses.fields(cls))


def test_nested_range_names_the_option():
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.params import GeometryParams, OccupancyParams

    with pytest.raises(PanovoccError, match=r"^--kappa must be > 0 and <= 10, got 11$"):
        validate_config(MapConfig(seq="s", out="o", geometry=GeometryParams(kappa=11.0)))
    with pytest.raises(PanovoccError, match=r"^--nu must be >= 0 and <= 1, got 1.5$"):
        validate_config(MapConfig(seq="s", out="o", occupancy=OccupancyParams(nu=1.5)))
    with pytest.raises(PanovoccError, match=r"^--stride must be >= 0 and <= 64, got 65$"):
        validate_config(MapConfig(seq="s", out="o", stride=65))
    with pytest.raises(PanovoccError, match="--voxel-size must be a finite number"):
        validate_config(MapConfig(seq="s", out="o", geometry=GeometryParams(voxel_size=float("nan"))))


def test_non_finite_numbers_are_refused_with_or_without_a_declared_range():
    """NaN and infinities are refused for every numeric option, those declared without a range included
    (--tau-s, --tau-w), and for those with only a lower bound (--lambda-n, --alpha)."""
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.params import GeometryParams, OccupancyParams

    for field, flag in (("tau_s", "--tau-s"), ("tau_w", "--tau-w"), ("lambda_n", "--lambda-n")):
        for bad in (float("nan"), float("inf"), -float("inf")):
            with pytest.raises(PanovoccError, match=f"^{flag} must be a finite number, got"):
                validate_config(MapConfig(seq="s", out="o", occupancy=OccupancyParams(**{field: bad})))
    with pytest.raises(PanovoccError, match="^--alpha must be a finite number, got inf$"):
        validate_config(MapConfig(seq="s", out="o", geometry=GeometryParams(alpha=float("inf"))))
    ok = MapConfig(seq="s", out="o", occupancy=OccupancyParams(tau_s=-0.5, tau_w=-1.0))
    assert validate_config(ok) == ok  # any finite threshold is a threshold


def test_choices_normalised_and_parity():
    from panovocc_cli.rendering.render import RenderConfig

    cfg = validate_config(RenderConfig(scene=Path("a"), out=Path("b"), noise=" Realistic"))
    assert cfg.noise == "realistic"
    with pytest.raises(PanovoccError, match=r"^--noise: 'loud' is not one of none, realistic$"):
        validate_config(RenderConfig(scene=Path("a"), out=Path("b"), noise="loud"))
    with pytest.raises(PanovoccError, match=r"^--width must be even, got 255$"):
        validate_config(RenderConfig(scene=Path("a"), out=Path("b"), width=255))


@pytest.mark.parametrize("call, message", [
    ("render_seed", "--seed must be >= 0 and <= 18446744073709551615, got -1"),
    ("render_threads", "--threads must be >= 0, got -2"),
    ("show_width", "--width-px must be >= 64 and <= 16384, got 10"),
    ("demo_frames", "--frames must be >= 2, got 1"),
    ("map_kappa", "--kappa must be > 0 and <= 10, got 0"),
    ("revise_none", None),
])
def test_python_api_refuses_what_the_cli_refuses_before_any_write(tmp_path, call, message):
    from panovocc_cli.demo import DemoConfig, run_demo
    from panovocc_cli.evaluation.run import ShowConfig, run_show
    from panovocc_cli.mapping.params import GeometryParams
    from panovocc_cli.mapping.pipeline import MapConfig, run_map, run_revise
    from panovocc_cli.rendering.render import RenderConfig, run_render

    out = tmp_path / "out"
    calls = {
        "render_seed": lambda: run_render(RenderConfig(scene=tmp_path / "none", out=out, seed=-1)),
        "render_threads": lambda: run_render(RenderConfig(scene=tmp_path / "none", out=out, threads=-2)),
        "show_width": lambda: run_show(ShowConfig(grids=[tmp_path / "g.npz"], out_png=out, width_px=10)),
        "demo_frames": lambda: run_demo(DemoConfig(out=out, frames=1)),
        "map_kappa": lambda: run_map(MapConfig(seq=str(tmp_path / "none"), out=str(out),
                                               geometry=GeometryParams(kappa=0.0))),
        "revise_none": lambda: run_revise(out, tmp_path / "poses.txt"),
    }
    with pytest.raises(PanovoccError) as e:
        calls[call]()
    if message is not None:
        assert str(e.value) == message
    assert "\n" not in str(e.value)
    assert not out.exists()


def test_run_synth_checks_its_output_like_the_cli(tmp_path):
    from panovocc_cli.datasets.synth import SynthConfig, run_synth

    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    with pytest.raises(PanovoccError, match="not a panovocc scene|--overwrite"):
        run_synth(SynthConfig(out=foreign, frames=2))
    with pytest.raises(PanovoccError):
        run_synth(SynthConfig(out=foreign, frames=2, overwrite=True))  # never replaces what synth did not write
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]

    scene = tmp_path / "scene"
    run_synth(SynthConfig(out=scene, seed=1, frames=2))
    with pytest.raises(PanovoccError, match="--overwrite"):
        run_synth(SynthConfig(out=scene, seed=2, frames=2))
    run_synth(SynthConfig(out=scene, seed=2, frames=2, overwrite=True))


def _seed_fields(cls, path=()):
    """(path of field names, option) of every seed option of a config class, nested configs included."""
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(f.type if isinstance(f.type, type) else None):
            yield from _seed_fields(f.type, path + (f.name,))
        elif "seed" in f.name and OPT_KEY in f.metadata:
            yield path + (f.name,), f.metadata[OPT_KEY]
        elif f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory):
            yield from _seed_fields(f.default_factory, path + (f.name,))


def _with_seed(cls, path, value):
    cfg = _with_required(cls, **({"name": "single-pano"} if cls.__name__ == "BaselineConfig" else {}))

    def put(obj, names):
        if len(names) == 1:
            return dataclasses.replace(obj, **{names[0]: value})
        return dataclasses.replace(obj, **{names[0]: put(getattr(obj, names[0]), names[1:])})
    return put(cfg, path)


def test_every_seed_fits_64_bits():
    """A seed beyond 64 bits was taken silently (numpy hashes any int); every seed option now says 0 .. 2^64 - 1."""
    from panovocc_cli.baselines.run import BaselineConfig
    from panovocc_cli.config import MAX_SEED
    from panovocc_cli.evaluation.trajectory_run import TrajPerturbConfig

    assert MAX_SEED == 2 ** 64 - 1
    seen = 0
    for cls in _configs() + [BaselineConfig, TrajPerturbConfig]:
        for path, o in _seed_fields(cls):
            seen += 1
            assert validate_config(_with_seed(cls, path, MAX_SEED)) is not None
            with pytest.raises(PanovoccError, match=rf"must be >= 0 and <= {MAX_SEED}, got {2 ** 64}$"):
                validate_config(_with_seed(cls, path, 2 ** 64))
    assert seen >= 8, seen
