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


@app.callback()
def _commands() -> None:
    """A group of commands whatever is registered: ``panovocc version`` registers only ``version``, and a Typer
    app with one command and no callback runs that command on its own (``panovocc version`` then refused the
    word ``version`` as an extra argument)."""
