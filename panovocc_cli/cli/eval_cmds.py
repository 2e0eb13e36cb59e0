"""Commands: eval, coverage, show, convert (replicaocc / to-replicaocc).

Thin wrappers: each builds a config and calls one ``run_*`` of :mod:`panovocc_cli.evaluation.run`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

from ..errors import PanovoccError
from ..evaluation.run import ConvertReplicaOccConfig, ConvertToReplicaOccConfig, CoverageConfig, EvalConfig, ShowConfig
from ._app import app
from .options import OptionValues, config_command

convert_app = typer.Typer(help="Bring data in: datasets to sequences (Holo360D, Stanford 2D-3D-S, ROS bags), ground "
                               "truth to grids (ReplicaOcc/FreeOcc .pkl, 2D-3D-S annotations) and back (docs/datasets.md).",
                          no_args_is_help=True, context_settings={"help_option_names": ["-h", "--help"]})
app.add_typer(convert_app, name="convert")


@config_command(app, EvalConfig, "eval", exclude=("pairs",), context_settings={"ignore_unknown_options": True})
def eval_cmd(
    o: OptionValues,
    paths: Optional[List[str]] = typer.Argument(
        None, help="PRED.npz GT.npz, then any number of '--pair PRED.npz GT.npz' (all pairs are pooled).",
        show_default=False, metavar="PRED GT [--pair PRED GT]..."),
    pairs: Optional[Path] = typer.Option(None, "--pairs", help="CSV listing pairs: pred,gt per line (relative to it)."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object (scores in percent) instead of a table."),
) -> None:
    """Score predictions against ground truth (FreeOcc protocol: IoU, per-class IoU, mIoU, percent).

    mIoU is FreeOcc's: the mean over every class of the set, a class absent from the ground truth
    scoring 0; the mean over the classes present is printed beside it when the two differ.
    """
    from ..evaluation.run import eval_json, format_report, run_eval
    from ..io.pairs import read_pairs_csv

    all_pairs = parse_pair_tokens(paths or [])
    if pairs is not None:
        all_pairs += read_pairs_csv(pairs)
    if o["out_dir"] is not None and pairs is not None:  # run_eval checks the pairs; the CSV is the command's
        from ..io.atomic import check_output

        check_output(o["out_dir"], "eval", o["overwrite"], inputs=[pairs])
    cfg = EvalConfig(pairs=all_pairs, **o)
    res = run_eval(cfg)
    if as_json:
        typer.echo(json.dumps(eval_json(res, cfg.mask)))
    else:
        typer.echo(format_report(res))
        if cfg.out_dir is not None:
            typer.echo(f"wrote scores.csv, scores.md, scores.tex, counts.csv, scores.json to {cfg.out_dir}")


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


@config_command(app, CoverageConfig, "coverage")
def coverage_cmd(
    o: OptionValues,
) -> None:
    """Fraction of GT occupied voxels observed so far, panorama vs. forward perspective camera (Fig. 5)."""
    from ..evaluation.run import run_coverage
    cfg = CoverageConfig(**o)
    r = run_coverage(cfg)
    n = len(r["frame"])
    typer.echo(f"coverage of {int(r['total'])} GT occupied voxels over {n} frames "
               f"(perspective {cfg.hfov_deg:g} x {float(r['vfov_deg']):.1f} deg):")
    typer.echo(f"{'frame':>8}{'panoramic':>12}{'perspective':>13}")
    for k in sorted({0, (n - 1) // 2, n - 1}):
        typer.echo(f"{int(r['frame'][k]):>8}{100 * r['panoramic'][k]:>11.2f}%{100 * r['perspective'][k]:>12.2f}%")
    typer.echo(f"wrote {cfg.out_dir / 'coverage.csv'} and {cfg.out_dir / 'coverage.png'}")


@config_command(app, ShowConfig, "show", exclude=("grids", "out_png"))
def show_cmd(
    o: OptionValues,
    paths: List[Path] = typer.Argument(..., help="GRID.npz [GRID2.npz ...] OUT.png: grids side by side, then the PNG."),
) -> None:
    """Render semantic occupancy grids as a picture (paper class colours, legend of classes present)."""
    from ..evaluation.run import run_show

    if len(paths) < 2:
        raise PanovoccError("expected GRID.npz [GRID2.npz ...] OUT.png")
    cfg = ShowConfig(grids=list(paths[:-1]), out_png=paths[-1], **o)
    h, w = run_show(cfg)
    typer.echo(f"wrote {cfg.out_png} ({w}x{h} px, {len(cfg.grids)} panel{'s' if len(cfg.grids) > 1 else ''})")


@config_command(convert_app, ConvertReplicaOccConfig, "replicaocc")
def convert_replicaocc_cmd(
    o: OptionValues,
) -> None:
    """ReplicaOcc .pkl (scene_dim, global_labels, global_pts[, global_mask]) -> grid .npz."""
    from ..evaluation.run import run_convert_replicaocc
    g, shift, names_from = run_convert_replicaocc(ConvertReplicaOccConfig(**o))
    occ = int(((g.labels != 0) & (g.labels != 255)).sum())
    src = {"given": "given", "file": "from the file", "replica": "FreeOcc's replica_name.txt"}[names_from]
    typer.echo(f"wrote {o['out_npz']}: {tuple(g.labels.shape)} voxels of {g.voxel_size:g} m, {occ} occupied, "
               f"{len(g.class_names) - 1} class names ({src})"
               + (f", shifted by {shift.round(4).tolist()} m" if shift.any() else ""))


@config_command(convert_app, ConvertToReplicaOccConfig, "to-replicaocc")
def convert_to_replicaocc_cmd(
    o: OptionValues,
) -> None:
    """Grid .npz -> ReplicaOcc .pkl that FreeOcc's load_full_scene_occ reads (voxel_size, class_names keys added)."""
    from ..evaluation.run import run_convert_to_replicaocc
    cfg = ConvertToReplicaOccConfig(**o)
    g, unmatched = run_convert_to_replicaocc(cfg)
    typer.echo(f"wrote {cfg.out_pkl}: scene_dim {list(g.labels.shape)} of {g.voxel_size:g} m, {cfg.ids} ids"
               + (", unknown written as 0 (prediction)" if cfg.prediction else "")
               + (f"; no Replica id for {', '.join(unmatched)} (written as 254, occupied)" if unmatched else ""))
