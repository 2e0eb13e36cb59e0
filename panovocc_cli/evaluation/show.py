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
from ..errors import PanovoccError, printable
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
            fig.text((i + 0.5) / n, 1.0 - 6 / height_px, printable(str(titles[i])), ha="center", va="top",
                     fontsize=13)
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
        ax.set_title(printable(title))
    fig.tight_layout()
    return fig


def floor_layers(grid: Grid, min_share: float = 0.3) -> list[int]:
    """The z layers (indices into ``grid.labels``) that hold a floor: layers whose ``floor`` voxels number at
    least ``min_share`` of the most in any layer; of consecutive such layers, the lowest. Bottom to top."""
    ids = [k for k, n in enumerate(grid.class_names) if canonical_name(n) == "floor"]
    if not ids:
        raise PanovoccError("no 'floor' class in the grid: cannot find its floors")
    count = np.isin(grid.labels, ids).sum(axis=(0, 1))
    levels = np.nonzero(count >= min_share * count.max())[0]
    return [int(k) for i, k in enumerate(levels) if i == 0 or levels[i - 1] != k - 1]


def plan_image(grid: Grid, floor_layer: int, height_m: float = 1.9) -> np.ndarray:
    """Top view of one storey, (Y, X, 3) uint8 with row 0 at the grid's smallest y: per column the class
    colour of the highest occupied voxel from just above ``floor_layer`` up to ``height_m`` metres (walls,
    furniture, stairs: under the ceiling), else that of the floor layer's voxel, white where neither."""
    from .render_grid import palette

    top = min(grid.labels.shape[2], floor_layer + 1 + int(round(height_m / grid.voxel_size)))
    slab = grid.labels[:, :, floor_layer + 1:top]
    occ = (slab != EMPTY) & (slab != UNKNOWN)
    k = slab.shape[2] - 1 - np.argmax(occ[:, :, ::-1], axis=2)  # highest occupied layer of each column
    lab = np.take_along_axis(slab, k[:, :, None], axis=2)[:, :, 0]
    base = grid.labels[:, :, floor_layer]
    lab = np.where(occ.any(axis=2), lab, np.where((base != EMPTY) & (base != UNKNOWN), base, EMPTY))
    rgb = palette(grid)[lab]
    rgb[lab == EMPTY] = 255
    return np.ascontiguousarray(rgb.transpose(1, 0, 2))


def floor_plans_figure(grid: Grid, T_world_cam: np.ndarray, title: str | None = None, width_px: int = 2000,
                       eye_min_m: float = 1.0, x_range: tuple[float, float] | None = None):
    """A floor plan per storey (:func:`plan_image`, bottom floor last) with the part of the walk that is on it:
    a line coloured by frame number (start ^, end s), world metres on both axes (``x_range``: only that part
    of the x axis, metres).

    A pose belongs to the highest floor at least ``eye_min_m`` below the camera, so on a staircase the walk
    moves to the next floor's panel half-way up. Returns a matplotlib Figure ``width_px`` wide.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Patch

    layers = floor_layers(grid)
    h = grid.voxel_size
    lo = grid.origin - h / 2
    hi = lo + np.array(grid.labels.shape) * h
    floor_z = lo[2] + np.array(layers) * h  # bottom face of each floor layer
    P = np.asarray(T_world_cam)[:, :3, 3]
    level = np.searchsorted(floor_z, P[:, 2] - eye_min_m, side="right") - 1
    n = len(layers)
    xlim = (lo[0], hi[0]) if x_range is None else (max(lo[0], x_range[0]), min(hi[0], x_range[1]))
    if xlim[1] <= xlim[0]:
        raise PanovoccError(f"x range {x_range} misses the grid's {lo[0]:.2f}..{hi[0]:.2f} m")
    aspect = (hi[1] - lo[1]) / (xlim[1] - xlim[0])
    panel_h = width_px * 0.9 * aspect
    legend = classes_present([grid], grid.index0, grid.index0 + np.array(grid.labels.shape) - 1)
    ncol = max(1, min(len(legend), int(width_px * 0.6 // 110)))
    head, foot = (40 if title else 10), 50 + 20 * math.ceil(len(legend) / ncol)
    height_px = int(round(n * (panel_h + 34) + head + foot))
    fig = plt.figure(figsize=(width_px / DPI, height_px / DPI), dpi=DPI)
    norm = plt.Normalize(0, max(1, len(P) - 1))
    for i, k in enumerate(layers[::-1]):
        f = n - 1 - i
        y0 = height_px - head - (i + 1) * (panel_h + 34)
        ax = fig.add_axes((0.05, y0 / height_px, 0.9, panel_h / height_px))
        ax.imshow(plan_image(grid, k), origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]), interpolation="nearest")
        on = level == f
        idx = np.nonzero(on)[0]
        if len(idx) > 1:
            pts = P[:, :2]
            segs = np.stack([pts[idx[:-1]], pts[idx[:-1] + 1]], 1)[np.diff(idx) == 1]
            lc = LineCollection(segs, cmap="viridis", norm=norm, linewidths=1.4)
            lc.set_array(idx[:-1][np.diff(idx) == 1].astype(float))
            ax.add_collection(lc)
            ax.plot(*pts[idx[0]], "^", color="black", ms=7)
            ax.plot(*pts[idx[-1]], "s", color="black", ms=6)
        ax.set_xlim(*xlim)
        ax.set_ylim(lo[1], hi[1])
        ax.tick_params(labelsize=8)
        ax.set_title(f"floor {f} (z = {floor_z[f]:.2f} m): frames {idx[0] if len(idx) else '-'}"
                     f"-{idx[-1] if len(idx) else '-'}", fontsize=10, loc="left")
    if title:
        fig.text(0.5, 1.0 - 8 / height_px, printable(title), ha="center", va="top", fontsize=13)
    sm = plt.cm.ScalarMappable(norm=norm, cmap="viridis")
    cax = fig.add_axes((0.05, 18 / height_px, 0.25, 12 / height_px))
    fig.colorbar(sm, cax=cax, orientation="horizontal").set_label("frame", fontsize=9)
    handles = [Patch(facecolor=_legend_color(c), edgecolor="0.3", label=c) for c in legend]
    fig.legend(handles=handles, loc="lower right", ncol=ncol, frameon=False, fontsize=9,
               bbox_to_anchor=(0.95, 0.0), handlelength=1.2, columnspacing=1.0)
    fig.set_facecolor("white")
    return fig
