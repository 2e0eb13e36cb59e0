"""Command: ``convert holo360d`` (a Holo360D scene -> a toolkit sequence, with the pose-convention check).

Registered on the ``convert`` group of :mod:`panovocc_cli.cli.eval_cmds` (imported first, COMMAND_MODULES)."""

from __future__ import annotations

import typer

from ..datasets.holo360d import ConvertHolo360dConfig
from .eval_cmds import convert_app
from .options import OptionValues, config_command


@config_command(convert_app, ConvertHolo360dConfig, "holo360d")
def convert_holo360d_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Convert a Holo360D scene (rgb/, depth/*_depth/*.exr, mask/, poses/*.txt) into a sequence; --check reports
    how well overlapping frames' depth agree under the chosen pose form and under every other one."""
    from ..datasets.holo360d import run_convert_holo360d

    s = run_convert_holo360d(ConvertHolo360dConfig(**o, progress=not quiet))
    typer.echo(f"{o['out']}: {s['frames']} frames {s['width']}x{s['height']}"
               + (f", {len(s['skipped'])} stems skipped (a modality missing: {s['skipped'][0]}"
                  + (", ..." if len(s['skipped']) > 1 else "") + ")" if s["skipped"] else ""))
    if s["check"] is not None:
        echo_check(s["check"])


def echo_check(c: dict) -> None:
    """Print a pose-convention check's report (datasets/holo360d.py ``pose_check``; also convert s2d3ds)."""
    if not c["pairs"]:
        typer.echo("check: fewer than two frames, nothing to compare")
        return
    typer.echo(f"check: {c['pairs']} frame pairs, median baseline {c['median_baseline_m']:.2f} m, "
               f"rotation {c['median_rotation_deg']:.1f} deg; depth agreement under {c['chosen']}: "
               f"{c['agreement']:.1f}%")
    others = ", ".join(f"{k} {v:.1f}%" for k, v in sorted(c["all"].items(), key=lambda kv: -kv[1]))
    typer.echo(f"check: every form: {others}")
    if c["best"] != c["chosen"] and c["all"][c["best"]] > c["agreement"] + 5.0:
        hint = c.get("hint") or (f"--pose-form {c['best'].split('/')[0]} --camera-axes {c['best'].split('/')[1]}")
        typer.echo(f"check: {c['best']} agrees better than the chosen {c['chosen']}: rerun with {hint}")
