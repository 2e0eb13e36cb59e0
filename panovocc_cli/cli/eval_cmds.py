"""Commands: eval, coverage, show, convert (replicaocc / to-replicaocc).

Thin wrappers: each builds a config and calls one ``run_*`` of :mod:`panovocc_cli.evaluation.run`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional, Tuple

import typer

from ..config import COVERAGE_TOL_M, DEFAULT_VOXEL_SIZE
from ..errors import PanovoccError
from ._app import app

convert_app = typer.Typer(help="Convert ground truth between the ReplicaOcc/FreeOcc .pkl form and grid .npz.",
                          no_args_is_help=True, context_settings={"help_option_names": ["-h", "--help"]})
app.add_typer(convert_app, name="convert")


@app.command("eval", context_settings={"ignore_unknown_options": True})
def eval_cmd(
    paths: Optional[List[str]] = typer.Argument(
        None, help="PRED.npz GT.npz, then any number of '--pair PRED.npz GT.npz' (all pairs are pooled).",
        show_default=False, metavar="PRED GT [--pair PRED GT]..."),
    pairs: Optional[Path] = typer.Option(None, "--pairs", help="CSV listing pairs: pred,gt per line (relative to it)."),
    classes: str = typer.Option("eval8", "--classes",
                                help="Class set for mIoU: eval8 | open4 | eval12 | all | comma list (a,b,c)."),
    mask: str = typer.Option("freeocc", "--mask", help="Mask for the --json top level: freeocc (headline) | observed."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object (scores in percent) instead of a table."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for scores.csv/.md/.tex, counts.csv, scores.json."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous eval output in --out (never any "
                                                             "other folder)."),
) -> None:
    """Score predictions against ground truth (FreeOcc protocol: IoU, per-class IoU, mIoU, percent).

    mIoU is FreeOcc's: the mean over every class of the set, a class absent from the ground truth
    scoring 0; the mean over the classes present is printed beside it when the two differ.
    """
    from ..evaluation.run import EvalConfig, eval_json, format_report, run_eval
    from ..io.pairs import read_pairs_csv

    all_pairs = parse_pair_tokens(paths or [])
    if pairs is not None:
        all_pairs += read_pairs_csv(pairs)
    if out is not None:
        from ..io.atomic import check_output

        check_output(out, "eval", overwrite, inputs=[p for pair in all_pairs for p in pair] + [pairs])
    cfg = EvalConfig(pairs=all_pairs, classes=classes, mask=mask.strip().lower(), out_dir=out)
    res = run_eval(cfg)
    if as_json:
        typer.echo(json.dumps(eval_json(res, cfg.mask)))
    else:
        typer.echo(format_report(res))
        if out is not None:
            typer.echo(f"wrote scores.csv, scores.md, scores.tex, counts.csv, scores.json to {out}")


def parse_pair_tokens(tokens: list[str]) -> list[tuple[Path, Path]]:
    """``PRED GT [--pair PRED GT]...`` -> pairs (``--pair`` is parsed here: Typer has no repeatable 2-value option)."""
    out, loose, k = [], [], 0
    while k < len(tokens):
        t = tokens[k]
        if t == "--pair":
            if k + 2 >= len(tokens) or any(x.startswith("-") for x in tokens[k + 1:k + 3]):
                raise PanovoccError("--pair needs two paths: --pair PRED.npz GT.npz")
            out.append((Path(tokens[k + 1]), Path(tokens[k + 2])))
            k += 3
        elif t.startswith("-"):
            raise PanovoccError(f"unknown option {t!r} (see panovocc eval --help)")
        else:
            loose.append(Path(t))
            k += 1
    if len(loose) % 2:
        raise PanovoccError("give both PRED and GT (paths come in pairs)")
    return [(loose[i], loose[i + 1]) for i in range(0, len(loose), 2)] + out


@app.command("coverage")
def coverage_cmd(
    seq: Path = typer.Argument(..., help="Panoramic (ERP) sequence folder: depth/ and poses.txt are used."),
    gt: Path = typer.Argument(..., help="Ground-truth grid .npz (its occupied voxels are the denominator)."),
    out: Path = typer.Option(..., "--out", help="Output folder for coverage.csv, coverage.png, config.json."),
    fov_deg: float = typer.Option(90.0, "--fov-deg", help="Perspective camera horizontal field of view, degrees."),
    vfov_deg: Optional[float] = typer.Option(
        None, "--vfov-deg", help="Perspective vertical field of view, degrees (default: from --aspect)."),
    aspect: float = typer.Option(1200.0 / 680.0, "--aspect",
                                 help="Perspective image width/height, used when --vfov-deg is not given "
                                      "(default: Replica's 1200x680)."),
    every: int = typer.Option(1, "--every", help="Use every K-th frame (the last frame is always used)."),
    tol_m: float = typer.Option(COVERAGE_TOL_M, "--tol-m", help="Metres: a depth point this close to a voxel face also "
                                                      "observes the voxel across it."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous coverage output in --out (never "
                                                             "any other folder)."),
) -> None:
    """Fraction of GT occupied voxels observed so far, panorama vs. forward perspective camera (Fig. 5)."""
    from ..evaluation.run import CoverageConfig, run_coverage
    from ..io.atomic import check_output

    check_output(out, "coverage", overwrite, inputs=(seq, gt))
    cfg = CoverageConfig(seq=seq, gt=gt, out_dir=out, hfov_deg=fov_deg, vfov_deg=vfov_deg, aspect=aspect,
                         every=every, tol_m=tol_m)
    r = run_coverage(cfg)
    n = len(r["frame"])
    typer.echo(f"coverage of {int(r['total'])} GT occupied voxels over {n} frames "
               f"(perspective {fov_deg:g} x {float(r['vfov_deg']):.1f} deg):")
    typer.echo(f"{'frame':>8}{'panoramic':>12}{'perspective':>13}")
    for k in sorted({0, (n - 1) // 2, n - 1}):
        typer.echo(f"{int(r['frame'][k]):>8}{100 * r['panoramic'][k]:>11.2f}%{100 * r['perspective'][k]:>12.2f}%")
    typer.echo(f"wrote {out / 'coverage.csv'} and {out / 'coverage.png'}")


@app.command("show")
def show_cmd(
    paths: List[Path] = typer.Argument(..., help="GRID.npz [GRID2.npz ...] OUT.png: grids side by side, then the PNG."),
    cut_top: int = typer.Option(0, "--cut-top", help="Remove the top K voxel layers (to look into rooms)."),
    titles: Optional[str] = typer.Option(None, "--titles", help="Comma-separated panel titles, one per grid."),
    width_px: int = typer.Option(1600, "--width-px", help="PNG width in pixels."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing OUT.png (never an input)."),
) -> None:
    """Render semantic occupancy grids as a picture (paper class colours, legend of classes present)."""
    from ..evaluation.run import ShowConfig, run_show

    if len(paths) < 2:
        raise PanovoccError("expected GRID.npz [GRID2.npz ...] OUT.png")
    from ..io.atomic import check_output

    check_output(paths[-1], "picture", overwrite, inputs=paths[:-1], folder=False)
    cfg = ShowConfig(grids=list(paths[:-1]), out_png=paths[-1], cut_top=cut_top,
                     titles=[t.strip() for t in titles.split(",")] if titles else None, width_px=width_px)
    h, w = run_show(cfg)
    typer.echo(f"wrote {cfg.out_png} ({w}x{h} px, {len(cfg.grids)} panel{'s' if len(cfg.grids) > 1 else ''})")


@convert_app.command("replicaocc")
def convert_replicaocc_cmd(
    pkl: Path = typer.Argument(..., help="ReplicaOcc/FreeOcc global_occ_package/<scene>.pkl (dense or flat form)."),
    out_npz: Path = typer.Argument(..., help="Output grid .npz."),
    class_names: Optional[str] = typer.Option(
        None, "--class-names", help="Names of the label ids: a text file (one a line), 'replica' or a comma list; "
                                    "ids 1.. unless the first name is empty/free/unlabeled (then ids 0..). "
                                    "Default: the file's class_names key, else FreeOcc's replica_name.txt (101)."),
    voxel_size: Optional[float] = typer.Option(
        None, "--voxel-size", help=f"Voxel edge, metres (default: the file's voxel_size key, else {DEFAULT_VOXEL_SIZE})."),
    tol_m: Optional[float] = typer.Option(None, "--tol-m", help="Metres a centre may be off the lattice "
                                                                "(default: a quarter voxel)."),
    allow_shift: bool = typer.Option(False, "--allow-shift", help="Translate an off-lattice grid onto the lattice."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing OUT_NPZ (never an input)."),
) -> None:
    """ReplicaOcc .pkl (scene_dim, global_labels, global_pts[, global_mask]) -> grid .npz."""
    from ..evaluation.run import ConvertReplicaOccConfig, run_convert_replicaocc
    from ..io.atomic import check_output

    names_file = Path(class_names) if class_names and "," not in class_names else None
    check_output(out_npz, "grid", overwrite, inputs=(pkl, names_file), folder=False)
    g, shift, names_from = run_convert_replicaocc(
        ConvertReplicaOccConfig(pkl, out_npz, class_names, voxel_size, tol_m, allow_shift))
    occ = int(((g.labels != 0) & (g.labels != 255)).sum())
    src = {"given": "given", "file": "from the file", "replica": "FreeOcc's replica_name.txt"}[names_from]
    typer.echo(f"wrote {out_npz}: {tuple(g.labels.shape)} voxels of {g.voxel_size:g} m, {occ} occupied, "
               f"{len(g.class_names) - 1} class names ({src})"
               + (f", shifted by {shift.round(4).tolist()} m" if shift.any() else ""))


@convert_app.command("to-replicaocc")
def convert_to_replicaocc_cmd(
    grid: Path = typer.Argument(..., help="Grid .npz (ground truth or prediction)."),
    out_pkl: Path = typer.Argument(..., help="Output .pkl in FreeOcc's dense global_occ_package form."),
    ids: str = typer.Option("replica", "--ids", help="Label ids to write: replica (FreeOcc's, 1 + line of "
                                                     "replica_name.txt, matched by name) | own (the grid's)."),
    prediction: bool = typer.Option(False, "--prediction",
                                    help="The grid is a prediction: write unknown (255) as 0, since FreeOcc's "
                                         "scripts count every label > 0 as occupied."),
    like: Optional[Path] = typer.Option(None, "--like", help="Ground-truth grid .npz whose voxels to write (FreeOcc "
                                                             "compares arrays index by index)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing OUT_PKL (never an input)."),
) -> None:
    """Grid .npz -> ReplicaOcc .pkl that FreeOcc's load_full_scene_occ reads (voxel_size, class_names keys added)."""
    from ..evaluation.run import ConvertToReplicaOccConfig, run_convert_to_replicaocc
    from ..io.atomic import check_output

    check_output(out_pkl, "pickle", overwrite, inputs=(grid, like), folder=False)

    g, unmatched = run_convert_to_replicaocc(ConvertToReplicaOccConfig(grid, out_pkl, ids.strip().lower(),
                                                                       prediction, like))
    typer.echo(f"wrote {out_pkl}: scene_dim {list(g.labels.shape)} of {g.voxel_size:g} m, {ids} ids"
               + (", unknown written as 0 (prediction)" if prediction else "")
               + (f"; no Replica id for {', '.join(unmatched)} (written as 254, occupied)" if unmatched else ""))
