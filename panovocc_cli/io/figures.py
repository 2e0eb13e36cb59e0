"""PNG pictures of matplotlib figures, written atomically and reproducibly.

No software tag or timestamp goes into the file (matplotlib's ``Software`` text chunk is dropped), so
the same figure gives the same bytes.
"""

from __future__ import annotations

from pathlib import Path

from .atomic import atomic_path

PNG_METADATA = {"Software": None}
DPI = 100


def write_png(fig, path: str | Path, dpi: int = DPI, facecolor: str | None = None) -> None:
    """Save a matplotlib ``Figure`` as a PNG at ``path`` atomically, then close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : output ``.png``
    dpi : dots per inch (the figure's size in inches times this is the size in pixels)
    facecolor : background colour (None: the figure's)
    """
    import matplotlib.pyplot as plt

    kw = {} if facecolor is None else {"facecolor": facecolor}
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png", metadata=PNG_METADATA, **kw)
    finally:
        plt.close(fig)
