"""Commands: ``traj eval`` (ATE / RPE of an estimated trajectory, as evo computes them) and ``traj perturb``
(a seeded drifting and jittered trajectory)."""

from __future__ import annotations

import typer

from ..evaluation.trajectory_run import TrajEvalConfig, TrajPerturbConfig
from ._app import app
from .options import OptionValues, config_command

traj_app = typer.Typer(help="Trajectories: accuracy against a reference (ATE, RPE), seeded drift and jitter.",
                       no_args_is_help=True)
app.add_typer(traj_app, name="traj")


@config_command(traj_app, TrajEvalConfig, "eval")
def traj_eval(o: OptionValues,
              overwrite: bool = typer.Option(False, "--overwrite", help="Replace --plot / --json files.")) -> None:
    """ATE RMSE after Umeyama alignment and RPE of EST against GT (poses matched by timestamp)."""
    from ..evaluation.trajectory_run import run_traj_eval

    r = run_traj_eval(TrajEvalConfig(**o), overwrite=overwrite)
    scale = f", scale {r.scale:.4f}" if r.align == "sim3" else ""
    typer.echo(f"{r.pairs} matched poses, alignment {r.align}{scale}")
    typer.echo(f"ATE  (m):   rmse {r.ate['rmse']:.4f}  mean {r.ate['mean']:.4f}  median {r.ate['median']:.4f}  "
               f"max {r.ate['max']:.4f}")
    typer.echo(f"RPE  (m):   rmse {r.rpe_trans['rmse']:.4f}  mean {r.rpe_trans['mean']:.4f}  "
               f"max {r.rpe_trans['max']:.4f}  (delta {r.rpe_delta} frame{'s' if r.rpe_delta > 1 else ''})")
    typer.echo(f"RPE (deg):  rmse {r.rpe_rot_deg['rmse']:.4f}  mean {r.rpe_rot_deg['mean']:.4f}  "
               f"max {r.rpe_rot_deg['max']:.4f}")


@config_command(traj_app, TrajPerturbConfig, "perturb")
def traj_perturb(o: OptionValues,
                 overwrite: bool = typer.Option(False, "--overwrite", help="Replace OUT.")) -> None:
    """Write a seeded perturbed copy of GT to OUT: random-walk drift (--drift, --drift-per-m, --rot-drift-deg),
    then independent per-frame jitter (--jitter, --rot-jitter-deg)."""
    from ..evaluation.trajectory_run import run_traj_perturb

    s = run_traj_perturb(TrajPerturbConfig(**o), overwrite=overwrite)
    typer.echo(f"{s['out']}: {s['poses']} poses, end position {s['end_error_m']:.3f} m from GT's")
