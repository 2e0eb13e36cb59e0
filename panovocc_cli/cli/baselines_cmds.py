"""Commands: ``baselines run`` (persp-tsdf, single-pano, forward-only on a panoramic sequence) and ``baselines
merge`` (per-view-sequence predictions of external models merged by the paper's rule).

Options are declared once, on BaselineConfig and MergeConfig (panovocc_cli/baselines/run.py)."""

from __future__ import annotations

from pathlib import Path
from typing import List

import typer

from ..baselines.run import BaselineConfig, MergeConfig
from ._app import app
from .options import OptionValues, config_command

baselines_app = typer.Typer(help="Baselines on the same inputs as map (persp-tsdf, single-pano, forward-only), and "
                                 "the merge of external models' per-view predictions.", no_args_is_help=True,
                            context_settings={"help_option_names": ["-h", "--help"]})
app.add_typer(baselines_app, name="baselines")


@config_command(baselines_app, BaselineConfig, "run")
def run_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Run a baseline on a panoramic sequence with map's poses and segmenter; writes OUT/prediction.npz
    (score it with panovocc eval)."""
    from ..baselines.run import run_baseline

    s = run_baseline(BaselineConfig(**o, progress=not quiet))
    pf = s.get("per_frame")
    extra = ""
    if pf:
        f = lambda x: "n/a" if x is None else f"{x:.2f}"  # noqa: E731  (None: undefined, e.g. empty union)
        extra = (f"; per frame in its box ({pf['classes']}): IoU {f(pf['mean_iou'])}, mIoU {f(pf['mean_miou'])} "
                 f"(mean), pooled IoU {f(pf['pooled_iou'])}, mIoU {f(pf['pooled_miou'])}")
    typer.echo(f"{s['baseline']}: {s['frames']} frames in {s['seconds']:.1f} s, {s['occupied']} occupied voxels, "
               f"{s['classed']} with a class -> {s['out']}/prediction.npz{extra}")


@config_command(baselines_app, MergeConfig, "merge")
def merge_cmd(o: OptionValues, inputs: List[Path] = typer.Argument(
        ..., metavar="INPUT...", help="One prediction per view sequence: grid .npz, ReplicaOcc .pkl (dense) or "
                                      "sparse voxels .npz.", show_default=False)) -> None:
    """Merge per-view-sequence predictions: occupied by union; classes by voting (dense) or by the most
    confident entry (sparse)."""
    from ..baselines.run import run_merge

    s = run_merge(MergeConfig(**o, inputs=list(inputs)))
    typer.echo(f"merged {s['inputs']} {s['kind']} predictions: {s['occupied']} occupied voxels, {s['classed']} with a "
               f"class, grid {'x'.join(map(str, s['shape']))} -> {s['out']}")
