"""Pictures: semantic occupancy grids side by side (``panovocc show``) and coverage curves (Fig. 5).

The voxels are drawn by :mod:`.render_grid` (numpy); matplotlib (Agg) only lays out panels, titles,
the legend and the plot axes. This module builds the figures; :func:`panovocc_cli.io.figures.write_png`
writes them (no timestamp or software tag, so the same input gives the same bytes).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..classes import DEFAULT_VOCAB, canonical_name, class_color
from ..errors import PanovoccError
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid
from .align import check_same_voxel_size
from .render_grid import NO_CLASS_COLOR, drawing_box, render_voxels

DPI = 100


def classes_present(grids: Sequence[Grid], lo: np.ndarray, hi: np.ndarray) -> list[str]:
    """Canonical names of the classes drawn in the box (benchmark classes first, then by name);
    ``"occupied (no class)"`` last when label 254 is drawn."""
    names: set[str] = set()
    no_class = False
    for g in grids:
        a0 = np.clip(lo - g.index0, 0, g.labels.shape)
        a1 = np.clip(hi + 1 - g.index0, 0, g.labels.shape)
        sub = g.labels[a0[0]:a1[0], a0[1]:a1[1], a0[2]:a1[2]]
        ids = np.unique(sub)
        for k in ids:
            if k in (EMPTY, UNKNOWN):
                continue
            if k == OCCUPIED_UNKNOWN_CLASS:
                no_class = True
            elif k < len(g.class_names):
                names.add(canonical_name(g.class_names[k]))
    order = [n for n in DEFAULT_VOCAB if n in names] + sorted(names - set(DEFAULT_VOCAB))
    return order + (["occupied (no class)"] if no_class else [])


def render_panels(grids: Sequence[Grid], cut_top: int = 0, panel_px: int = 800):
    """Render several grids in one common lattice box (so a prediction and its ground truth line up).

    Returns
    -------
    images : list of (H, W, 3) uint8, all the same size
    legend : list[str], classes drawn
    """
    if not grids:
        raise PanovoccError("nothing to show: no grids given")
    for g in grids[1:]:
        check_same_voxel_size(grids[0], g)
    if cut_top < 0:
        raise PanovoccError(f"--cut-top must be >= 0, got {cut_top}")
    lo, hi, z_keep = drawing_box(list(grids), cut_top)
    if z_keep is None:
        raise PanovoccError("nothing to show: no grid has an occupied voxel")
    if hi[2] < lo[2]:
        raise PanovoccError(f"--cut-top {cut_top} removes every occupied layer ({int(hi[2] + cut_top - lo[2] + 1)} "
                            "layers are occupied)")
    shape = hi - lo + 1
    u = max(1, int(panel_px // int(shape[0] + shape[1])))
    images = [render_voxels(g, lo, hi, u)[0] for g in grids]
    return images, classes_present(grids, lo, hi)


def _legend_color(name: str) -> tuple[float, float, float]:
    rgb = NO_CLASS_COLOR if name == "occupied (no class)" else class_color(name)
    return tuple(c / 255.0 for c in rgb)  # type: ignore[return-value]


def panels_figure(images: Sequence[np.ndarray], legend: Sequence[str], titles: Sequence[str] | None = None,
                  width_px: int = 1600):
    """Lay rendered panels side by side with titles and a class legend.

    Returns
    -------
    fig : matplotlib Figure of ``width_px`` x height pixels at :data:`DPI` (white background)
    (height, width) : its size in pixels (width = ``width_px``)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    n = len(images)
    ih, iw = images[0].shape[:2]
    panel_w = width_px / n
    panel_h = panel_w * ih / iw
    title_h = 36 if titles else 8
    ncol = max(1, min(len(legend), int(width_px // 170)))
    legend_h = 16 + 22 * math.ceil(len(legend) / ncol) if legend else 0
    height_px = int(round(panel_h + title_h + legend_h))
    fig = plt.figure(figsize=(width_px / DPI, height_px / DPI), dpi=DPI)
    for i, img in enumerate(images):
        ax = fig.add_axes((i / n, (legend_h) / height_px, 1.0 / n, panel_h / height_px))
        ax.imshow(img, interpolation="antialiased")
        ax.set_axis_off()
        if titles:
            fig.text((i + 0.5) / n, 1.0 - 6 / height_px, str(titles[i]), ha="center", va="top", fontsize=13)
    if legend:
        handles = [Patch(facecolor=_legend_color(c), edgecolor="0.3", label=c) for c in legend]
        fig.legend(handles=handles, loc="lower center", ncol=ncol, frameon=False, fontsize=10,
                   bbox_to_anchor=(0.5, 0.0), handlelength=1.2, columnspacing=1.2)
    fig.set_facecolor("white")
    return fig, (height_px, width_px)


def coverage_figure(frames: np.ndarray, panoramic: np.ndarray, perspective: np.ndarray,
                    title: str | None = None, hfov_deg: float = 90.0):
    """Coverage curves (percent of GT occupied voxels observed so far) against the frame number.

    Returns a matplotlib Figure (6 x 4 inches at :data:`DPI`).

    Parameters
    ----------
    frames : (n,) int, 0-based frame indices (plotted 1-based: "camera location N")
    panoramic, perspective : (n,) float fractions in [0, 1]
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.asarray(frames) + 1
    marks = sorted({0, (len(x) - 1) // 2, len(x) - 1})
    fig, ax = plt.subplots(figsize=(6.0, 4.0), dpi=DPI)
    for y, label, color in ((panoramic, "panoramic (360°)", "#d62728"),
                            (perspective, f"perspective ({hfov_deg:g}° HFOV)", "#1f77b4")):
        y = 100.0 * np.asarray(y)
        ax.plot(x, y, color=color, lw=2, label=label)
        ax.plot(x[marks], y[marks], "o", color=color, ms=6)
        for m in marks:
            ax.annotate(f"{y[m]:.2f}%", (x[m], y[m]), textcoords="offset points", xytext=(0, 7), ha="center",
                        fontsize=8, color=color)
    for m in marks:
        ax.axvline(x[m], color="0.6", ls=":", lw=1)
    ax.set_xlabel("camera location N (frame)")
    ax.set_ylabel("occupied coverage (% of GT occupied voxels)")
    ax.set_ylim(0, 105)
    ax.set_xlim(x[0] - 0.5 if len(x) > 1 else 0.5, x[-1] + 0.5 if len(x) > 1 else 1.5)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig
