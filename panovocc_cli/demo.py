"""``panovocc demo``: the whole pipeline on the embedded default scene, with no download.

synth (procedural scene, Replica format) -> gt (mesh ground truth) -> render (ERP RGB-D sequence)
-> map (PanOVOcc memory + semantics) -> eval (FreeOcc protocol) -> pictures (prediction vs ground truth,
coverage curves). Every stage is the same ``run_*`` function its own command calls, so the demo's outputs
are exactly what a user gets running the commands one by one (README, "Step by step").
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .config import DEFAULT_SEED, DEFAULT_WIDTH, MAX_SEED, MIN_WIDTH, NOISE_MODELS, option, validate_config


@dataclass
class DemoConfig:
    """Options of ``panovocc demo`` (each field's help is its ``--help`` text).

    out : working folder (scene/, seq/, gt.npz, map/, eval/, compare.png, coverage/, config.json)
    seed : seed of the procedural scene, the render noise and the simulated segmenter
    frames : trajectory poses (>= 2); width : ERP width in pixels (even, >= MIN_WIDTH)
    noise : depth noise of the render: none | realistic
    """

    out: Path = option(Path("work/demo"), argument=True, help="Working folder for every stage's outputs.")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED,
                       help="Seed of the procedural scene, render noise and segmenter.")
    frames: int = option(60, min=2, help="Number of trajectory poses (frames).")
    width: int = option(DEFAULT_WIDTH, min=MIN_WIDTH, even=True,
                        help="ERP width in pixels (even; height = width / 2).")
    noise: str = option("none", choices=NOISE_MODELS, help="Depth noise of the render: none | realistic.")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous demo's outputs in OUT (never any other folder).")


def check_demo_config(cfg: DemoConfig) -> DemoConfig:
    """Refuse bad option values before any stage runs or writes (:class:`PanovoccError`); returns the checked
    config (choices normalised)."""
    return validate_config(cfg)  # seed, frames, width (even, >= MIN_WIDTH), noise: declared on DemoConfig


def _stage(name: str, fn: Callable[[], object], timings: dict[str, float], log) -> object:
    t0 = time.perf_counter()
    print(f"[{len(timings) + 1}] {name} ...", file=log, flush=True)
    result = fn()
    timings[name] = time.perf_counter() - t0
    print(f"    {name} done in {timings[name]:.1f} s", file=log, flush=True)
    return result


def run_demo(cfg: DemoConfig, log=sys.stderr) -> dict:
    """Run every stage into ``cfg.out``; returns {"scores": eval output, "timings": {stage: s}, "paths": {...}}.

    Every stage saves its own resolved config beside its outputs; the demo's own goes to
    ``OUT/config.json`` once all stages succeeded.
    """
    from .datasets.synth import SynthConfig, run_synth
    from .evaluation.run import CoverageConfig, EvalConfig, ShowConfig, run_coverage, run_eval, run_show
    from .gt import GtConfig, run_gt
    from .io.atomic import check_output
    from .io.runconfig import CONFIG_NAME, write_run_config
    from .mapping.pipeline import MapConfig, run_map
    from .mapping.config import SemanticParams
    from .rendering.render import RenderConfig, run_render

    cfg = check_demo_config(cfg)
    out = Path(cfg.out)
    check_output(out, "demo", cfg.overwrite)  # the stages below replace only what a demo wrote in ``out``
    scene, seq, gt, mapped = out / "scene", out / "seq", out / "gt.npz", out / "map"
    t: dict[str, float] = {}
    _stage("synth", lambda: run_synth(SynthConfig(out=scene, seed=cfg.seed, frames=cfg.frames, overwrite=True)), t, log)
    _stage("gt", lambda: run_gt(GtConfig(scene=scene, out=gt, overwrite=True)), t, log)
    _stage("render", lambda: run_render(RenderConfig(scene=scene, out=seq, width=cfg.width, noise=cfg.noise,
                                                     seed=cfg.seed, progress=cfg.progress,
                                                     overwrite=True)), t, log)
    sem = SemanticParams(seed=cfg.seed)  # the simulated segmenter's noise follows --seed too
    _stage("map", lambda: run_map(MapConfig(seq=str(seq), out=str(mapped), semantic=sem), overwrite=True,
                                  progress=cfg.progress), t, log)
    pred = mapped / "prediction.npz"
    scores = _stage("eval", lambda: run_eval(EvalConfig(pairs=[(pred, gt)], classes="eval12",
                                                        out_dir=out / "eval", overwrite=True)), t, log)
    _stage("show", lambda: run_show(ShowConfig(grids=[pred, gt], out_png=out / "compare.png", cut_top=3,
                                               titles=["PanOVOcc prediction", "ground truth"],
                                               overwrite=True)), t, log)
    _stage("coverage", lambda: run_coverage(CoverageConfig(seq=seq, gt=gt, out_dir=out / "coverage",
                                                           progress=cfg.progress, overwrite=True)), t, log)
    write_run_config(out / CONFIG_NAME, cfg)
    paths = {"scene": scene, "sequence": seq, "ground_truth": gt, "map": mapped, "prediction": pred,
             "tables": out / "eval", "picture": out / "compare.png", "coverage": out / "coverage" / "coverage.png",
             "config": out / CONFIG_NAME}
    return {"scores": scores, "timings": t, "paths": paths}
