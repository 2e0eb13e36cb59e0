"""The Typer application object shared by the command modules."""

import typer

app = typer.Typer(
    name="panovocc",
    help="Panoramic open-vocabulary 3D semantic occupancy mapping: render, map, evaluate.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

