"""Commands: ``map`` (sequence -> persistent semantic memory + grid), ``revise`` (new poses), ``bench`` (speed),
``segeval`` (a segmenter's own per-frame 2D mIoU)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..config import DEFAULT_SEED, DEFAULT_WIDTH
from ..errors import PanovoccError
from ..mapping.params import GeometryParams, OccupancyParams
from ._app import app

_G, _O = GeometryParams(), OccupancyParams()  # defaults shown in --help (a light module: no numba import)


def _given(**values) -> dict:
    """The options the user set (not None): they override the parameter dataclasses' defaults."""
    return {k: v for k, v in values.items() if v is not None}


@app.command("map")
def map_cmd(
    seq: Optional[Path] = typer.Argument(None, help="Sequence folder (CONVENTIONS.md layout); omit with --resume."),
    out: Optional[Path] = typer.Argument(None, help="Output folder for the memory, prediction.npz and map.ply."),
    poses: Optional[Path] = typer.Option(None, help="Pose file (NICE-SLAM or TUM); default SEQ/poses.txt."),
    voxel_size: float = typer.Option(_G.voxel_size, help="Voxel edge length h, metres."),
    stride: int = typer.Option(0, help="Pixel stride s of the kernel lift; 0 = auto, max(1, W // 256) (4 at 1024)."),
    kernel: str = typer.Option("psvf", help="Surface kernel: psvf (anisotropic Gaussian) or point (ablation)."),
    checkpoint_every: int = typer.Option(25, help="Checkpoint the memory every K frames (0 = only at the end)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the interrupted run in OUT (its config is used)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a map already in OUT."),
    kappa: Optional[float] = typer.Option(None, help=f"Mahalanobis truncation radius kappa (dimensionless) (default: {_G.kappa})."),
    alpha: Optional[float] = typer.Option(
        None, help=f"Radial kernel scale alpha in sigma_r = alpha r + beta (dimensionless) (default: {_G.alpha})."),
    beta: Optional[float] = typer.Option(None, help=f"Radial kernel scale beta, metres (default: {_G.beta})."),
    eps_abs: Optional[float] = typer.Option(
        None, help=f"Free-space margin eps_abs in eps(r) = eps_abs + eps_rel r, metres (default: {_G.eps_abs})."),
    eps_rel: Optional[float] = typer.Option(
        None, help=f"Free-space margin eps_rel (dimensionless, per metre of range) (default: {_G.eps_rel})."),
    max_range: Optional[float] = typer.Option(
        None, help=f"Depths and voxels farther than this are ignored, metres (default: {_G.max_range})."),
    rule: Optional[str] = typer.Option(
        None, help=f"Occupancy rule: frequency (N/O - lambda_n F/O >= nu) or score (the paper's g with tau_s, "
                   f"tau_w, gamma_f) (default: {_O.rule})."),
    nu: Optional[float] = typer.Option(
        None, help=f"Frequency rule: least share of valid observations that saw surface in the voxel (0..1) "
                   f"(default: {_O.nu})."),
    lambda_n: Optional[float] = typer.Option(
        None, help=f"Frequency rule: weight of the free-space share F/O (default: {_O.lambda_n})."),
    lambda_f: Optional[float] = typer.Option(
        None, help=f"Score rule: weight lambda_f of the free-space ratio in the signed score (default: {_O.lambda_f})."),
    tau_s: Optional[float] = typer.Option(
        None, help=f"Score rule: strong support threshold tau_s on g (per-frame support units) (default: {_O.tau_s})."),
    tau_w: Optional[float] = typer.Option(None, help=f"Score rule: weak support threshold tau_w on g (default: {_O.tau_w})."),
    gamma_f: Optional[float] = typer.Option(
        None, help=f"Score rule: largest free-space ratio F/O for weak support (0..1) (default: {_O.gamma_f})."),
    segmenter: Optional[str] = typer.Option(
        None, help="Semantic segmenter: simulated (from SEQ/semantic/ labels) | precomputed:DIR | none (geometry "
                   "only, occupied voxels 254). Default: simulated when SEQ has labels, else you must choose."),
    vocab: Optional[str] = typer.Option(
        None, help="Vocabulary chosen at run time: class names and sets, comma- or +-separated "
                   "(eval8, open4, eval12, e.g. 'eval8,pillow'); default eval8,open4."),
    noise: Optional[float] = typer.Option(
        None, help="Simulated segmenter noise level (dimensionless; 1 = default realistic errors, 0 = exact)."),
    seed: Optional[int] = typer.Option(None, help=f"Seed of the simulated segmenter's noise (default {DEFAULT_SEED})."),
    no_gsc: bool = typer.Option(False, "--no-gsc", help="Ablation: raw argmax of the fused evidence, no GSC."),
    ply_color: Optional[str] = typer.Option(
        None, help="map.ply colours: class (class colours, grey = no class) | rgb (mean pixel colour) | height."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Map a panoramic RGB-D sequence into a persistent semantic occupancy memory (OUT/) and grid
    (OUT/prediction.npz), labelling occupied voxels with classes of the vocabulary."""
    from ..mapping.pipeline import MapConfig, run_map
    from ..mapping.semantic import SemanticParams

    if resume:
        target = out if out is not None else seq
        if target is None or (seq is not None and out is not None):
            raise PanovoccError("--resume takes only the output folder: panovocc map --resume OUT")
        given = [n for n, v in (("--segmenter", segmenter), ("--vocab", vocab), ("--noise", noise), ("--seed", seed),
                                ("--ply-color", ply_color)) if v is not None] + (["--no-gsc"] if no_gsc else [])
        if given:
            raise PanovoccError(f"--resume reuses the run's saved config; {', '.join(given)} cannot change it")
        summary = run_map(resume_out=target, progress=not quiet)
    else:
        if seq is None or out is None:
            raise PanovoccError("map needs SEQ and OUT (or --resume OUT)")
        if segmenter is None:
            if not (seq / "semantic").is_dir() and (seq / "meta.json").is_file():
                raise PanovoccError(f"{seq} has no ground-truth labels (semantic/) for the default simulated "
                                    "segmenter: pass --segmenter precomputed:DIR, or --segmenter none (geometry only)")
            segmenter = "auto"
        geo = GeometryParams(voxel_size=voxel_size, kernel=kernel, **_given(
            kappa=kappa, alpha=alpha, beta=beta, eps_abs=eps_abs, eps_rel=eps_rel, max_range=max_range))
        occ = OccupancyParams(**_given(rule=rule, nu=nu, lambda_n=lambda_n, lambda_f=lambda_f, tau_s=tau_s, tau_w=tau_w,
                                       gamma_f=gamma_f))
        sem = SemanticParams(segmenter=segmenter, vocab=vocab, noise=1.0 if noise is None else noise,
                             seed=DEFAULT_SEED if seed is None else seed, use_gsc=not no_gsc, ply_color=ply_color or "class")
        cfg = MapConfig(seq=str(seq), out=str(out), poses=None if poses is None else str(poses),
                        checkpoint_every=checkpoint_every, geometry=geo, occupancy=occ, stride=stride, semantic=sem)
        summary = run_map(cfg, overwrite=overwrite, progress=not quiet)
    classed = f", {summary['classed']} with a class" if "classed" in summary else ""
    seg = f", segmenter {summary['segmenter_ms_per_frame']:.1f} ms" if "segmenter_ms_per_frame" in summary else ""
    typer.echo(f"mapped {summary['integrated']} of {summary['frames']} frames, {summary['ms_per_frame']:.1f} ms/frame "
               f"(update {summary['update_ms_per_frame']:.1f} ms{seg}): {summary['occupied']} occupied{classed}, "
               f"{summary['free']} free voxels -> {summary['out']}")
    empty = summary.get("empty_frames") or []
    if empty:
        shown = ", ".join(map(str, empty[:10])) + (", ..." if len(empty) > 10 else "")
        typer.echo(f"{len(empty)} frame(s) had no valid depth and were mapped as empty observations: {shown}")


@app.command()
def revise(
    out: Path = typer.Argument(..., help="Output folder of a finished `panovocc map` run."),
    poses: Path = typer.Argument(..., help="Full pose file (one pose per frame, NICE-SLAM or TUM form)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Re-integrate exactly the frames whose pose changed, and rewrite OUT/prediction.npz and OUT/map.ply."""
    from ..mapping.pipeline import run_revise

    s = run_revise(out, poses, progress=not quiet)
    classed = f", {s['classed']} with a class" if "classed" in s else ""
    typer.echo(f"revised {s['revised']} of {s['frames']} frames in {s['seconds']:.2f} s: {s['occupied']} occupied"
               f"{classed}, {s['free']} free voxels")


@app.command()
def segeval(
    seq: Path = typer.Argument(..., help="Sequence folder with ground-truth labels (semantic/)."),
    segmenter: str = typer.Option("simulated", help="Segmenter to score: simulated | precomputed:DIR."),
    vocab: Optional[str] = typer.Option(None, help="Vocabulary (as for map); default eval8,open4."),
    noise: float = typer.Option(1.0, help="Simulated segmenter noise level (dimensionless; 0 = exact)."),
    seed: int = typer.Option(DEFAULT_SEED, help="Seed of the simulated segmenter's noise."),
    classes: str = typer.Option("eval8", help="Scored class set: eval8 | open4 | eval12 | comma list (a,b,c)."),
    every: int = typer.Option(1, help="Score every K-th frame (frames 0, K, 2K, ...)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """A segmenter's own per-frame 2D mIoU on a labelled sequence (pixel counts pooled over frames)."""
    import math

    from ..mapping.semantic import SegevalConfig, run_segeval

    res, frames = run_segeval(SegevalConfig(seq=str(seq), segmenter=segmenter, vocab=vocab, noise=noise, seed=seed,
                                            classes=classes, every=every), progress=not quiet)
    for (name, v), here in zip(res.iou.items(), res.present):
        shown = "-" if math.isnan(v) else f"{100 * v:5.1f}"
        typer.echo(f"  {name:<12} {shown}{'' if here else '  (absent from the ground truth, not in the mean)'}")
    typer.echo(f"2D mIoU ({classes}, pooled over {len(frames)} frames): {100 * res.miou:.1f}%, "
               f"pixel accuracy {100 * res.accuracy:.1f}%")


@app.command()
def bench(
    outdir: Path = typer.Argument(..., help="Working folder (the rendered sequence, the map, bench.json)."),
    frames: int = typer.Option(40, help="Frames of the benchmark sequence."),
    width: int = typer.Option(DEFAULT_WIDTH, help="ERP width of the benchmark sequence, pixels (height = width / 2)."),
) -> None:
    """Mapper speed against Open3D VoxelBlockGrid TSDF fusion (cube faces) on the same frames."""
    from ..mapping.bench import BenchConfig, run_bench

    r = run_bench(BenchConfig(out=str(outdir), frames=frames, width=width))
    typer.echo(r["line"])
