"""Camera trajectories through a procedural home: clearance map, shortest paths through waypoints, camera motion.

The path joins waypoints (two wide-open viewpoints per room, points either side of each door, in the order
a layout's *tour* gives) by clearance-weighted shortest paths over a ``RASTER`` occupancy raster of the
walls and the furniture footprints (``Home.obstacles``), is smoothed as far as ``CLEARANCE`` allows, and
sampled by arc length; the camera rides at 1.27-1.63 m with small pitch and roll and a slow look-around.
"""

from __future__ import annotations

import numpy as np

from ..geometry.poses import look_at
from .layout import WALL_T, LayoutRetry, Room

CLEARANCE = 0.30  # minimum camera distance to walls and furniture, metres
PLAN_CLEARANCE = 0.33  # clearance demanded of the raster path (margin for smoothing)
RASTER = 0.05  # planning raster, metres
CAM_Z = (1.2, 1.7)  # camera height range above the floor, metres
MAX_TILT_DEG = 6.0  # |pitch| and |roll| bound of the trajectory, degrees


def clearance_map(house):
    """Conservative 2-D clearance (metres) to walls and obstacles on a RASTER grid; returns (dist, lo)."""
    from scipy import ndimage

    rooms = house.rooms
    lo = np.array([min(r.x0 for r in rooms) - 0.5, min(r.y0 for r in rooms) - 0.5])
    hi = np.array([max(r.x1 for r in rooms) + 0.5, max(r.y1 for r in rooms) + 0.5])
    n = np.ceil((hi - lo) / RASTER).astype(int)
    cx = lo[0] + (np.arange(n[0]) + 0.5) * RASTER
    cy = lo[1] + (np.arange(n[1]) + 0.5) * RASTER
    free = np.zeros(n, bool)

    def cells(box, grow):
        ix = (cx > box[0] - grow) & (cx < box[1] + grow)
        iy = (cy > box[2] - grow) & (cy < box[3] + grow)
        return np.ix_(ix, iy)

    for r in rooms:
        free[cells((r.x0, r.x1, r.y0, r.y1), -RASTER / 2)] = True
        for o in r.openings:
            if o.kind == "door" and o.owner:
                free[cells(r.aabb(o.side, o.s0, o.s1, -0.1, WALL_T + 0.1), -RASTER / 2)] = True
    for b in house.obstacles:
        free[cells(b, RASTER / 2)] = False
    dist = (ndimage.distance_transform_edt(free) - 0.71) * RASTER
    return np.where(free, dist, -1.0), lo


def sample_clearance(dist, lo, pts):
    """Bilinear lookup of the clearance map at world points (n, 2)."""
    from scipy import ndimage

    ij = (np.asarray(pts) - lo) / RASTER - 0.5
    return ndimage.map_coordinates(dist, ij.T, order=1, mode="nearest")


def route(house, frames: int, rng: np.random.Generator, tour) -> np.ndarray:
    """``frames`` poses (frames, 4, 4) float64 T_world_cam along :func:`plan_path`'s path for ``tour``."""
    sm = plan_path(house, tour)
    xy = resample(sm, frames)
    return orient(xy, sm, rng)


def plan_path(house, tour, reach: float | None = None) -> np.ndarray:
    """The clearance-weighted shortest path through the waypoints ``tour`` gives, smoothed: (n, 2) float64
    metres, points about 5 cm apart, every one at least ``CLEARANCE`` from walls and obstacles.

    ``tour(house, centers, views, snap)`` returns raster node ids; ``views(room)`` gives a room's two
    wide-open viewpoints, ``snap(xy, room)`` the free node nearest a point (inside ``room`` when given).
    ``reach`` (metres, None = unbounded) bounds each shortest-path search to that path cost beyond a
    leg's straight-line length, so that a large floor's many short legs do not each search all of it; a
    leg not found within it is searched again unbounded.
    """
    from scipy import ndimage, sparse
    from scipy.sparse import csgraph

    dist, lo = clearance_map(house)
    ok = dist >= PLAN_CLEARANCE
    nx, ny = ok.shape
    ids = -np.ones(ok.shape, np.int64)
    ids[ok] = np.arange(ok.sum())
    rows, cols, wts = [], [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        sa = (slice(max(0, -dx), nx - max(0, dx)), slice(max(0, -dy), ny - max(0, dy)))
        sb = (slice(max(0, dx), nx - max(0, -dx)), slice(max(0, dy), ny - max(0, -dy)))
        m = ok[sa] & ok[sb]
        da = np.minimum(dist[sa], dist[sb])[m]
        rows.append(ids[sa][m])
        cols.append(ids[sb][m])
        wts.append(RASTER * np.hypot(dx, dy) * (1.0 + 0.15 / np.maximum(da, 0.05)))
    g = sparse.coo_matrix((np.concatenate(wts), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(int(ok.sum()),) * 2).tocsr()
    ci, cj = np.nonzero(ok)
    centers = lo + (np.stack([ci, cj], 1) + 0.5) * RASTER

    def snap(p, room: Room | None = None):
        d = np.linalg.norm(centers - p, axis=1)
        if room is not None:
            inside = ((centers[:, 0] > room.x0) & (centers[:, 0] < room.x1) & (centers[:, 1] > room.y0)
                      & (centers[:, 1] < room.y1))
            d = np.where(inside, d, np.inf)
        k = int(np.argmin(d))
        if d[k] > 0.35:
            raise LayoutRetry
        return k

    dist_ok = np.where(ok, dist, -1.0)

    def views(r: Room) -> list[int]:
        long_x = (r.x1 - r.x0) >= (r.y1 - r.y0)
        out = []
        for half in (0, 1):
            if long_x:
                xm = (r.x0 + r.x1) / 2
                box = (r.x0, xm, r.y0, r.y1) if half == 0 else (xm, r.x1, r.y0, r.y1)
            else:
                ym = (r.y0 + r.y1) / 2
                box = (r.x0, r.x1, r.y0, ym) if half == 0 else (r.x0, r.x1, ym, r.y1)
            inside = ((centers[:, 0] > box[0]) & (centers[:, 0] < box[1]) & (centers[:, 1] > box[2])
                      & (centers[:, 1] < box[3]))
            if not inside.any():
                raise LayoutRetry
            score = np.where(inside, dist_ok[ci, cj], -np.inf)
            out.append(int(np.argmax(score)))
        return out

    way = tour(house, centers, views, snap)
    path = [centers[way[0]]]
    for a, b in zip(way[:-1], way[1:]):
        if a == b:
            continue
        pred = None
        if reach is not None:
            limit = 1.5 * np.linalg.norm(centers[a] - centers[b]) + reach  # weights <= 1.46 x length
            _, pred = csgraph.dijkstra(g, directed=False, indices=a, return_predecessors=True, limit=limit)
        if pred is None or pred[b] < 0:
            _, pred = csgraph.dijkstra(g, directed=False, indices=a, return_predecessors=True)
        if pred[b] < 0:
            raise LayoutRetry
        seg = [b]
        while seg[-1] != a:
            seg.append(int(pred[seg[-1]]))
        path += [centers[k] for k in seg[::-1][1:]]
    path = np.array(path)
    # Resample densely, smooth while clearance allows (the poses are then taken by arc length).
    dense = resample(path, max(2, int(path_length(path) / 0.05)))
    for sigma in (8.0, 5.0, 3.0, 1.5, 0.0):
        sm = ndimage.gaussian_filter1d(dense, sigma, axis=0, mode="nearest") if sigma else dense
        if sample_clearance(dist, lo, sm).min() >= CLEARANCE:
            break
    else:
        raise LayoutRetry
    return sm


def path_length(p: np.ndarray) -> float:
    """Length (metres) of the polyline ``p`` (n, d)."""
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def resample(p: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced by arc length along the polyline ``p`` (m, d), both ends kept."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, p[:, k]) for k in range(p.shape[1])], axis=1)


def orient(xy: np.ndarray, dense: np.ndarray, rng) -> np.ndarray:
    """Camera poses (n, 4, 4) float64 T_world_cam (OpenCV axes) along the sampled path ``xy`` (n, 2) metres,
    or (n, 3) whose third column is the height of the floor (or stair) under the camera.

    Height 1.45 +- 0.18 m above that floor, pitch within 4 degrees, roll within 2.5, heading along the
    path plus a +-25 degree look-around; their slow waves have a period set by the length of ``dense``
    (the polyline ``xy`` was sampled from) and phases drawn from ``rng``.
    """
    from scipy import ndimage

    n = len(xy)
    u = np.linspace(0.0, 1.0, n)
    L = path_length(dense)
    cyc = max(1.0, L / 6.0)
    ph = rng.uniform(0, 2 * np.pi, 5)
    floor = xy[:, 2] if xy.shape[1] > 2 else 0.0
    z = floor + 1.45 + 0.18 * np.sin(2 * np.pi * cyc * u + ph[0])
    pitch = np.deg2rad(4.0) * np.sin(2 * np.pi * cyc * 1.3 * u + ph[1])
    roll = np.deg2rad(2.5) * np.sin(2 * np.pi * cyc * 0.8 * u + ph[2])
    tang = np.gradient(xy[:, :2], axis=0) if n > 1 else np.array([[1.0, 0.0]])
    yaw = np.unwrap(np.arctan2(tang[:, 1], tang[:, 0]))
    yaw = ndimage.gaussian_filter1d(yaw, 1.5, mode="nearest") + np.deg2rad(25) * np.sin(2 * np.pi * cyc * 0.5 * u + ph[3])
    T = np.empty((n, 4, 4))
    for k in range(n):
        fwd = np.array([np.cos(yaw[k]) * np.cos(pitch[k]), np.sin(yaw[k]) * np.cos(pitch[k]), np.sin(pitch[k])])
        Tk = look_at([xy[k, 0], xy[k, 1], z[k]], fwd)
        c, s = np.cos(roll[k]), np.sin(roll[k])
        Tk[:3, :3] = Tk[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        T[k] = Tk
    return T

