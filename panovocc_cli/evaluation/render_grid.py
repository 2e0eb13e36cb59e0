"""A fast voxel renderer for semantic occupancy grids (pure numpy, no OpenGL).

A parallel projection along ``(1, 1, -2)`` (about 55 degrees below the horizon, steep enough to
see into rooms over their walls): the viewer looks down from above the ``(-x, -y)`` corner, so the
visible faces of a voxel are its top (+z) and its -x and -y sides. Voxel ``(i, j, k)`` (relative to
the drawing box) has its screen anchor at integer pixels ``col = u (i - j)``, ``row = -u (i + j + k)``
with ``u`` pixels a unit, so the faces of neighbouring voxels tile the image exactly. Each face is a precomputed pixel sprite with a per-pixel
depth; faces hidden by a neighbour are culled, and the rest are resolved with a z-buffer
(``np.minimum.at``). Faces are shaded by orientation (top 1.0, -x 0.80, -y 0.64) and, at ``u >= 3``,
their edges are darkened so single voxels can be counted.

Colours are fixed per class name (:func:`panovocc_cli.classes.class_color`: the paper's for the 12
benchmark classes), 254 (occupied, no class) is grey, empty (0) and unknown (255) are not drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..classes import canonical_name, class_color
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

NO_CLASS_COLOR = (150, 150, 150)
BACKGROUND = (255, 255, 255)
FACE_SHADE = (1.0, 0.80, 0.64)  # top, -x side, -y side
EDGE_SHADE = 0.82
MAX_SCALE = 12


def palette(grid: Grid) -> np.ndarray:
    """Colour of every label id of a grid, (256, 3) uint8; ids 0 and 255 are black (never drawn)."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    for k, name in enumerate(grid.class_names[1:], start=1):
        lut[k] = class_color(canonical_name(name))
    lut[OCCUPIED_UNKNOWN_CLASS] = NO_CLASS_COLOR
    return lut


@dataclass(frozen=True)
class _Face:
    dcol: np.ndarray  # (p,) int64 pixel offsets from the voxel's anchor
    drow: np.ndarray
    depth: np.ndarray  # (p,) float64 depth offset along the view direction, larger = farther
    shade: np.ndarray  # (p,) float64


def _sprites(u: int) -> list[_Face]:
    """Pixel sprites of the three visible faces of a unit voxel at ``u`` pixels a unit (exact half-open tiling).

    A point ``(x, y, z)`` of the voxel maps to ``col = u (x - y)``, ``row = -u (x + y) - u z``.
    """
    c, r = np.meshgrid(np.arange(-u, u), np.arange(-3 * u, 0), indexing="xy")
    c, r = c.ravel(), r.ravel()
    cc, rr = (c + 0.5) / u, (r + 0.5) / u
    faces = []
    a, b = cc, -rr - 1.0  # top face z = 1: x - y = a, x + y = b
    faces.append(((a + b) / 2, (b - a) / 2, np.ones_like(a)))
    y = -cc  # -x face x = 0
    faces.append((np.zeros_like(y), y, -rr - y))
    x = cc  # -y face y = 0
    faces.append((x, np.zeros_like(x), -rr - x))
    out = []
    for f, (x, y, z) in enumerate(faces):
        p, q = [(x, y), (y, z), (x, z)][f]
        inside = (p >= 0) & (p < 1) & (q >= 0) & (q < 1)
        edge = np.minimum(np.minimum(p, 1 - p), np.minimum(q, 1 - q))[inside]
        shade = np.full(edge.shape, FACE_SHADE[f])
        if u >= 3:
            shade = np.where(edge < 0.75 / u, shade * EDGE_SHADE, shade)
        out.append(_Face(c[inside], r[inside], (x + y - 2 * z)[inside], shade))
    return out


def drawing_box(grids: list[Grid], cut_top: int = 0) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Common lattice box of the occupied voxels of several grids.

    Returns
    -------
    lo, hi : (3,) int64 lattice indices (inclusive) of the box (lo > hi when nothing is occupied)
    z_keep : highest lattice z kept after removing the top ``cut_top`` layers (None if nothing occupied)
    """
    lo = np.full(3, np.iinfo(np.int64).max)
    hi = np.full(3, np.iinfo(np.int64).min)
    for g in grids:
        occ = (g.labels != EMPTY) & (g.labels != UNKNOWN)
        if not occ.any():
            continue
        ext = [np.flatnonzero(occ.any(axis=tuple(a for a in range(3) if a != d))) for d in range(3)]
        lo = np.minimum(lo, g.index0 + [e[0] for e in ext])
        hi = np.maximum(hi, g.index0 + [e[-1] for e in ext])
    if np.any(lo > hi):
        return lo, hi, None
    z_keep = int(hi[2]) - int(cut_top)
    hi = hi.copy()
    hi[2] = max(z_keep, lo[2] - 1)
    return lo, hi, z_keep


def image_size(box_shape, u: int) -> tuple[int, int]:
    """(height, width) in pixels of the drawing of a box of ``box_shape`` voxels at ``u`` pixels a unit."""
    X, Y, Z = (int(v) for v in box_shape)
    return u * (X + Y + Z), u * (X + Y)


def render_voxels(grid: Grid, lo: np.ndarray, hi: np.ndarray, u: int) -> tuple[np.ndarray, np.ndarray]:
    """Render a grid's occupied voxels inside the lattice box ``[lo, hi]``.

    Parameters
    ----------
    grid : Grid
    lo, hi : (3,) int64, inclusive lattice box (voxels outside are not drawn: use it to cut the top)
    u : int >= 1, pixels per unit (a voxel's top is a 2 u x 2 u diamond)

    Returns
    -------
    rgb : (H, W, 3) uint8, background white; size from :func:`image_size`
    drawn : (H, W) bool, pixels covered by a voxel
    """
    u = int(max(1, min(u, MAX_SCALE)))
    shape = np.maximum(np.asarray(hi) - np.asarray(lo) + 1, 0)
    H, W = image_size(shape, u)
    img = np.empty((H, W, 3), dtype=np.uint8)
    img[:] = BACKGROUND
    drawn = np.zeros((H, W), dtype=bool)
    if H == 0 or W == 0:
        return img, drawn
    # the grid's labels inside the box, as a padded occupancy volume (1-voxel border for culling)
    a0 = np.asarray(lo) - grid.index0
    a1 = np.asarray(hi) + 1 - grid.index0
    src_lo = np.clip(a0, 0, grid.labels.shape)
    src_hi = np.clip(a1, 0, grid.labels.shape)
    lab = np.full(tuple(shape + 2), UNKNOWN, dtype=np.uint8)
    if np.all(src_hi > src_lo):
        d_lo = src_lo - a0 + 1
        d_hi = d_lo + (src_hi - src_lo)
        lab[d_lo[0]:d_hi[0], d_lo[1]:d_hi[1], d_lo[2]:d_hi[2]] = grid.labels[
            src_lo[0]:src_hi[0], src_lo[1]:src_hi[1], src_lo[2]:src_hi[2]]
    occ = (lab != EMPTY) & (lab != UNKNOWN)
    lut = palette(grid)
    X, Y, Z = (int(v) for v in shape)
    col0, row0 = u * Y, u * (X + Y + Z)
    neighbours = [(0, 0, 1), (-1, 0, 0), (0, -1, 0)]  # top, -x, -y
    zbuf = np.full(H * W, np.inf, dtype=np.float64)
    batches = []
    for face, (dx, dy, dz) in zip(_sprites(u), neighbours):
        inner = occ[1:-1, 1:-1, 1:-1] & ~occ[1 + dx:X + 1 + dx, 1 + dy:Y + 1 + dy, 1 + dz:Z + 1 + dz]
        i, j, k = np.nonzero(inner)
        if i.size == 0:
            continue
        cols = (col0 + u * (i - j))[:, None] + face.dcol[None, :]
        rows = (row0 - u * (i + j + k))[:, None] + face.drow[None, :]
        pix = (rows * W + cols).ravel()
        dep = ((i + j - 2 * k).astype(np.float64)[:, None] + face.depth[None, :]).ravel()
        colour = lut[lab[i + 1, j + 1, k + 1]].astype(np.float64)  # (n, 3)
        np.minimum.at(zbuf, pix, dep)
        batches.append((pix, dep, colour, face.shade, face.shade.size))
    flat = img.reshape(-1, 3)
    for pix, dep, colour, shade, p in batches:
        win = dep <= zbuf[pix]
        vox = np.flatnonzero(win) // p
        px = np.flatnonzero(win) % p
        flat[pix[win]] = np.clip(colour[vox] * shade[px, None] + 0.5, 0, 255).astype(np.uint8)
    drawn.reshape(-1)[np.isfinite(zbuf)] = True
    return img, drawn
