"""The toolkit's data as Rerun archetypes, under one entity layout (docs/viz.md).

Entities (world frame: the toolkit's, right-handed, +Z up; metres)::

    world                       ViewCoordinates RIGHT_HAND_Z_UP (static)
    world/map                   AnnotationContext: grid label -> class name and colour (static)
    world/map/occupied          Boxes3D, one box a occupied voxel, class_ids = grid labels (1..C, 254 no class)
    world/map/free              Points3D, observed free voxel centres (optional)
    world/trajectory            LineStrips3D, the camera centres in frame order
    world/frusta                LineStrips3D, a small wire pyramid a panorama: the view of its centre column
    world/camera                Transform3D (timeline ``frame``): T_world_cam of the current frame
    world/camera/axes           TransformAxes3D (x red right, y green down, z blue forward: OpenCV)
    world/diff/{false_positive,false_negative,wrong_class}  Boxes3D (``view --gt``)
    world/slam/loop_closures    LineStrips3D between the two keyframes of each loop edge (``map --rerun``)
    panorama, depth             Image / DepthImage (timeline ``frame``): the frame's ERP panorama and depth
    legend                      TextDocument (markdown): classes, colours, voxel counts
    log                         TextLog: revisions, loop closures, the run's summary

Nothing here opens a file or prints: :func:`open_stream` returns a recording stream bound to a sink
(an ``.rrd`` file, a running viewer, or a viewer it spawns) and the callers log into it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..classes import canonical_name, class_color
from ..errors import PanovoccError
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

APP_ID = "panovocc"
TIMELINE = "frame"
NO_CLASS_COLOR = (150, 150, 150)
NO_CLASS_NAME = "occupied (no class)"
DIFF_COLORS = {"false_positive": (230, 60, 50), "false_negative": (50, 110, 230), "wrong_class": (250, 170, 30)}
"""Colours of the prediction/ground-truth difference: occupied only in the prediction, only in the truth, or
occupied in both with a different class name."""
FRUSTUM_M = 0.1
"""Metres: depth of the wire pyramid drawn for each panorama (its centre column's 90-degree view)."""
FREE_RADIUS_FRACTION = 0.15
"""Free voxels are drawn as points of this fraction of the voxel edge."""


def require_rerun():
    """The ``rerun`` module, or one line saying how to install it."""
    try:
        import rerun as rr
    except ImportError:
        raise PanovoccError("the Rerun view needs rerun-sdk: pip install 'panovocc[viz]' (make setup installs it)") \
            from None
    return rr


def open_stream(rrd: str | Path | None = None, connect: str | None = None, spawn: bool = False,
                recording_id: str = "panovocc", eye=None):
    """A recording stream for the application ``panovocc``.

    Parameters
    ----------
    rrd : write the recording to this ``.rrd`` file (the caller renames it into place)
    connect : stream to a running viewer at this gRPC URL (``rerun+http://127.0.0.1:9876/proxy``); ``""`` = the
        default local viewer
    spawn : start a native viewer and stream to it
    recording_id : the recording's id (fixed, so two logs of the same map are the same recording)
    eye : the 3D view's starting camera (:func:`blueprint`)

    Wall-clock log times are not recorded (only the ``frame`` timeline and the log tick), so the same data
    logged twice holds the same values; Rerun's own row and chunk ids still differ between runs.
    """
    rr = require_rerun()
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.set_log_time_enabled(False)
    bp = blueprint(eye)
    if spawn:
        rec.spawn(connect=True, default_blueprint=bp)
    elif connect is not None:
        rec.connect_grpc(connect or None, default_blueprint=bp)
    elif rrd is not None:
        rec.save(str(rrd), default_blueprint=bp)
    else:
        raise ValueError("open_stream needs rrd, connect or spawn")
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def blueprint(eye=None):
    """The viewer's layout: the 3D map (``world``) on the left; the panorama, its depth, and the legend and text
    log (tabs) on the right. ``eye``: (position (3,), look target (3,)) metres, world, of the 3D view's camera."""
    import rerun.blueprint as rrb

    kw = {}
    if eye is not None:
        kw["eye_controls"] = rrb.EyeControls3D(position=[float(v) for v in eye[0]],
                                               look_target=[float(v) for v in eye[1]], eye_up=[0.0, 0.0, 1.0])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="map", **kw),
            rrb.Vertical(rrb.Spatial2DView(origin="panorama", name="panorama"),
                         rrb.Spatial2DView(origin="depth", name="depth (mm)"),
                         rrb.Tabs(rrb.TextDocumentView(origin="legend", name="legend"),
                                  rrb.TextLogView(origin="log", name="log"))),
            column_shares=[3, 2]),
        collapse_panels=True)


def class_table(class_names) -> list[tuple[int, str, tuple[int, int, int]]]:
    """(grid label, name, RGB colour) of every class of a grid's ``class_names`` (label 0 "empty" left out) and
    of label 254 (occupied, no class)."""
    rows = [(k, str(n), class_color(str(n))) for k, n in enumerate(class_names) if k > 0]
    return rows + [(OCCUPIED_UNKNOWN_CLASS, NO_CLASS_NAME, NO_CLASS_COLOR)]


def annotation_context(class_names):
    """``AnnotationContext`` mapping grid labels to class names and colours (the viewer's legend on hover)."""
    rr = require_rerun()
    return rr.AnnotationContext([rr.AnnotationInfo(id=k, label=n, color=c) for k, n, c in class_table(class_names)])


def cut_top(grid: Grid, z_keep: int | None) -> Grid:
    """The grid with every voxel above lattice layer ``z_keep`` set to 255 (not drawn; ``None``: unchanged)."""
    if z_keep is None:
        return grid
    lab = grid.labels.copy()
    lab[:, :, max(0, int(z_keep) - int(grid.index0[2]) + 1):] = UNKNOWN
    return Grid(lab, grid.origin, grid.voxel_size, grid.class_names)


def overview_eye(grid: Grid):
    """A 3D view's camera looking down at the grid's occupied voxels from above one corner (position, target)."""
    centres, _ = occupied_voxels(grid)
    if not len(centres):
        return None
    lo, hi = centres.min(axis=0), centres.max(axis=0)
    mid, ext = 0.5 * (lo + hi), hi - lo
    return mid + np.array([-0.45 * ext[0], -0.75 * ext[1], 0.6 * max(ext[0], ext[1])]), mid


def occupied_voxels(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """World centres (n, 3) float64 metres and labels (n,) uint8 of a grid's occupied voxels (label not 0 or 255)."""
    lab = grid.labels
    ijk = np.argwhere((lab != EMPTY) & (lab != UNKNOWN))
    return grid.centers(ijk), lab[tuple(ijk.T)]


def free_voxels(grid: Grid) -> np.ndarray:
    """World centres (n, 3) float64 metres of a grid's observed free voxels (label 0)."""
    return grid.centers(np.argwhere(grid.labels == EMPTY))


def voxel_boxes(centres: np.ndarray, voxel_size: float, class_ids=None, color=None):
    """``Boxes3D`` of voxels: solid boxes of edge ``voxel_size`` (metres) at ``centres`` (n, 3), coloured by
    ``class_ids`` (through the annotation context) or one ``color``."""
    rr = require_rerun()
    h = 0.5 * float(voxel_size)
    kw = {}
    if class_ids is not None:
        kw["class_ids"] = np.asarray(class_ids, np.uint16)
    if color is not None:
        kw["colors"] = [color]
    return rr.Boxes3D(centers=np.asarray(centres, np.float32), half_sizes=[[h, h, h]], fill_mode="solid",
                      show_labels=False, **kw)


def legend_markdown(grid: Grid, title: str = "Classes") -> str:
    """A markdown table of the classes a grid's occupied voxels carry: colour, name, voxel count."""
    lab = grid.labels
    counts = np.bincount(lab.ravel(), minlength=256)
    lines = [f"## {title}", "", "| colour | class | voxels |", "|---|---|---|"]
    for k, name, c in class_table(grid.class_names):
        if counts[k]:
            lines.append(f"| `#{c[0]:02x}{c[1]:02x}{c[2]:02x}` | {name} | {int(counts[k])} |")
    return "\n".join(lines) + "\n"


def log_grid(rec, grid: Grid, free: bool = False, entity: str = "world/map", static: bool = True) -> dict:
    """Log a grid's occupied voxels (boxes coloured by class) and, with ``free``, its free voxels (points).

    Returns the counts logged (``occupied``, ``free``)."""
    rr = require_rerun()
    centres, labels = occupied_voxels(grid)
    rec.log(entity, annotation_context(grid.class_names), static=True)
    rec.log(f"{entity}/occupied", voxel_boxes(centres, grid.voxel_size, class_ids=labels), static=static)
    out = {"occupied": int(len(centres)), "free": 0}
    if free:
        pts = free_voxels(grid)
        rec.log(f"{entity}/free", rr.Points3D(pts.astype(np.float32), radii=FREE_RADIUS_FRACTION * grid.voxel_size,
                                              colors=[(200, 200, 200)]), static=static)
        out["free"] = int(len(pts))
    return out


def grid_difference(pred: Grid, gt: Grid) -> dict[str, np.ndarray]:
    """World centres (n, 3) float64 of the prediction/ground-truth difference on the truth's scored voxels.

    Scored voxels are the ground truth's voxels not 255 (CONVENTIONS.md, "Scoring"); a prediction voxel
    outside the truth's grid is dropped and a truth voxel the prediction does not cover is not occupied.
    ``false_positive``: occupied in the prediction only; ``false_negative``: in the truth only;
    ``wrong_class``: occupied in both, class names differ (a prediction without class, 254, is not counted).
    """
    from ..evaluation.align import check_same_voxel_size, resample_onto

    check_same_voxel_size(pred, gt, "prediction and ground truth")
    p = resample_onto(pred, gt, fill=UNKNOWN)
    g = gt.labels
    scored = g != UNKNOWN
    occ_p = (p != EMPTY) & (p != UNKNOWN) & scored
    occ_g = (g != EMPTY) & scored
    pn = np.array([""] + [canonical_name(n) for n in pred.class_names[1:]] + [""] * 256, object)
    gn = np.array([""] + [canonical_name(n) for n in gt.class_names[1:]] + [""] * 256, object)
    both = occ_p & occ_g & (p != OCCUPIED_UNKNOWN_CLASS) & (g != OCCUPIED_UNKNOWN_CLASS)
    wrong = np.zeros_like(both)
    idx = np.nonzero(both)
    wrong[idx] = pn[p[idx]] != gn[g[idx]]
    return {"false_positive": gt.centers(np.argwhere(occ_p & ~occ_g)),
            "false_negative": gt.centers(np.argwhere(occ_g & ~occ_p)),
            "wrong_class": gt.centers(np.argwhere(wrong))}


def log_difference(rec, pred: Grid, gt: Grid, entity: str = "world/diff") -> dict:
    """Log :func:`grid_difference` as coloured boxes; returns the voxel count of each kind."""
    diff = grid_difference(pred, gt)
    for kind, centres in diff.items():
        rec.log(f"{entity}/{kind}", voxel_boxes(centres, gt.voxel_size, color=DIFF_COLORS[kind]), static=True)
    return {k: int(len(v)) for k, v in diff.items()}


def frustum_strips(T_world_cam: np.ndarray, size: float = FRUSTUM_M) -> list[np.ndarray]:
    """Wire pyramids (one closed strip and four edges a pose) of the centre column's 90-degree view of each
    panorama: apex at the camera, base ``size`` metres ahead along its +z (OpenCV: x right, y down).

    T_world_cam : (n, 4, 4) float64. Returns a list of (k, 3) float32 polylines."""
    T = np.asarray(T_world_cam, np.float64).reshape(-1, 4, 4)
    s = float(size)
    base = np.array([[-s, -s, s], [s, -s, s], [s, s, s], [-s, s, s]])
    strips = []
    for M in T:
        c = M[:3, 3]
        b = base @ M[:3, :3].T + c
        strips.append(np.vstack([b, b[:1]]).astype(np.float32))
        strips.extend(np.stack([c, b[k]]).astype(np.float32) for k in range(4))
    return strips


def log_poses(rec, T_world_cam: np.ndarray, static: bool = True) -> None:
    """The trajectory (camera centres in order) and every panorama's frustum."""
    rr = require_rerun()
    T = np.asarray(T_world_cam, np.float64).reshape(-1, 4, 4)
    if not len(T):
        return
    rec.log("world/trajectory", rr.LineStrips3D([T[:, :3, 3].astype(np.float32)], colors=[(255, 255, 255)]),
            static=static)
    rec.log("world/frusta", rr.LineStrips3D(frustum_strips(T), colors=[(255, 220, 0)]), static=static)


def log_camera(rec, T_world_cam: np.ndarray) -> None:
    """The current frame's pose (Transform3D at ``world/camera``) and its axes."""
    rr = require_rerun()
    T = np.asarray(T_world_cam, np.float64)
    rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    rec.log("world/camera/axes", rr.TransformAxes3D(0.3))


def log_frame_images(rec, rgb: np.ndarray | None, depth: np.ndarray | None, max_width: int = 0,
                     jpeg_quality: int = 90) -> None:
    """The frame's panorama (JPEG) and radial depth (millimetres, uint16), at most ``max_width`` pixels wide
    (0 = as they are; a 2:1 panorama is subsampled by a whole factor)."""
    rr = require_rerun()
    ref = rgb if rgb is not None else depth
    if ref is None:
        return
    step = 1
    if max_width and ref.shape[1] > max_width:
        step = int(np.ceil(ref.shape[1] / max_width))
    if rgb is not None:
        img = np.ascontiguousarray(rgb[::step, ::step])
        rec.log("panorama", rr.Image(img).compress(jpeg_quality=jpeg_quality))
    if depth is not None:
        d = np.asarray(depth, np.float64)[::step, ::step]
        mm = np.where(np.isfinite(d) & (d > 0) & (d < 65.535), np.rint(d * 1000.0), 0).astype(np.uint16)
        rec.log("depth", rr.DepthImage(mm, meter=1000.0))


def log_text(rec, text: str, level: str = "INFO") -> None:
    """One line in the ``log`` entity (the viewer's text log)."""
    rr = require_rerun()
    rec.log("log", rr.TextLog(text, level=level))


def log_markdown(rec, entity: str, text: str) -> None:
    rr = require_rerun()
    rec.log(entity, rr.TextDocument(text, media_type="text/markdown"), static=True)


def log_loop_closures(rec, edges, positions: dict) -> None:
    """Line segments between the camera centres of each loop edge's two keyframes (frame ids)."""
    rr = require_rerun()
    strips = [np.stack([positions[a], positions[b]]).astype(np.float32) for a, b in edges
              if a in positions and b in positions]
    if strips:
        rec.log("world/slam/loop_closures", rr.LineStrips3D(strips, colors=[(255, 0, 255)], radii=0.02))
