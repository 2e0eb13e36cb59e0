"""One perspective stream fused with Open3D's tensor ``VoxelBlockGrid`` TSDF, read out on the global lattice.

The perspective baselines (``persp-tsdf``, ``forward-only``) feed each view sequence into one
:class:`TsdfStream`: z-depth and colour go into a ``VoxelBlockGrid`` (attributes ``tsdf``, ``weight``,
``color``; truncation :data:`TRUNC_VOXELS` voxels, block resolution 8, CPU), and each pixel's class (the
segmenter's argmax, resampled into the view) votes for the lattice voxel its back-projected depth point
falls in. Nothing here reads or writes files.

Lattice alignment: Open3D puts TSDF samples at ``i h`` in the frame it integrates in. The stream
integrates in the world frame shifted by ``-h/2`` on every axis, so sample ``i`` sits at ``(i + 1/2) h``
in the world: the centre of lattice voxel ``i`` (CONVENTIONS.md). Then

* **occupied**: the voxels holding a point of ``extract_point_cloud(weight_threshold)`` (the TSDF's
  zero crossings, interpolated between neighbouring samples: each crossing falls in the voxel of the
  sample nearer to the surface);
* **free**: the other voxels whose sample has weight >= the threshold and a positive TSDF (seen in front
  of a surface, within the truncation band: a TSDF stores nothing farther from surfaces);
* everything else is unobserved (255); the grid spans the box of the occupied and free voxels (the rule
  of the mapper's prediction, mapping/export.py).

Class of an occupied voxel: the class with most pixel votes in it; when no pixel fell in it, the class with
most votes summed over its 26 neighbours; none there either: 254 (occupied, no class). Ties go to the
smaller class id.
"""

from __future__ import annotations

import numpy as np

from ..geometry.cameras import PinholeCamera
from ..geometry.lattice import index_to_center, pack_keys, point_to_index, unpack_keys
from ..grid import EMPTY, OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

#: TSDF truncation in voxels (``panovocc bench``'s Open3D run uses it too: benchmark/bench.py).
TRUNC_VOXELS = 3.0
#: Open3D's voxel blocks are 8^3 voxels.
BLOCK_RESOLUTION = 8
#: Votes are compacted (summed per voxel and class) every this many pixel votes.
_COMPACT_EVERY = 4_000_000

_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                        if (i, j, k) != (0, 0, 0)], np.int64)


class TsdfStream:
    """One perspective stream: an Open3D TSDF plus per-voxel class votes on the global lattice.

    Parameters
    ----------
    camera : PinholeCamera of every frame of the stream
    voxel_size : float, metres (the lattice's h)
    n_classes : int, C (class ids 0..C-1 of the per-pixel labels; 0 = geometry only)
    min_range, max_range : float, metres; z-depths outside are dropped (the map's ``min_range``/``max_range``)
    weight_threshold : float, least TSDF weight (frames that saw the voxel) for occupied and free
    trunc_voxels : float, TSDF truncation in voxels
    """

    def __init__(self, camera: PinholeCamera, voxel_size: float, n_classes: int = 0, *, min_range: float = 0.1,
                 max_range: float = 12.0, weight_threshold: float = 1.0, trunc_voxels: float = TRUNC_VOXELS):
        import open3d as o3d
        import open3d.core as o3c

        self.camera = camera
        self.h = float(voxel_size)
        self.n_classes = int(n_classes)
        self.min_range, self.max_range = float(min_range), float(max_range)
        self.weight_threshold = float(weight_threshold)
        self.trunc_voxels = float(trunc_voxels)
        self._o3d, self._o3c = o3d, o3c
        self._vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=self.h, block_resolution=BLOCK_RESOLUTION,
            block_count=1000, device=o3c.Device("CPU:0"))  # the hash map grows as blocks are added
        self._K = o3c.Tensor(camera.K, o3c.float64)
        self._shift = np.eye(4)
        self._shift[:3, 3] = -0.5 * self.h  # world -> the integration frame (samples at voxel centres)
        self._dirs = camera.backproject(np.ones(camera.shape))  # (h, w, 3) rays with z = 1
        self._keys: list[np.ndarray] = []
        self._cls: list[np.ndarray] = []
        self._cnt: list[np.ndarray] = []
        self._pending = 0
        self.frames = 0

    def integrate(self, depth_z: np.ndarray, T_world_view: np.ndarray, rgb: np.ndarray | None = None,
                  classes: np.ndarray | None = None) -> None:
        """Add one frame of the stream.

        Parameters
        ----------
        depth_z : (h, w) float, metres, z-depth, 0 = invalid
        T_world_view : (4, 4) float64, view-to-world pose (OpenCV axes)
        rgb : (h, w, 3) uint8 or None (black)
        classes : (h, w) int class ids 0..C-1 (negative: no vote) or None
        """
        o3d, o3c = self._o3d, self._o3c
        d = np.asarray(depth_z, np.float32).copy()
        d[~np.isfinite(d) | (d < self.min_range) | (d > self.max_range)] = 0.0
        self.frames += 1
        if not np.any(d > 0):
            return
        T = np.asarray(T_world_view, np.float64)
        ext = o3c.Tensor(np.linalg.inv(self._shift @ T), o3c.float64)
        img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(d)))
        col = np.zeros(d.shape + (3,), np.float32) if rgb is None else np.asarray(rgb, np.float32) / 255.0
        colour = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(col)))
        trunc = self.trunc_voxels
        blocks = self._vbg.compute_unique_block_coordinates(img, self._K, ext, 1.0, self.max_range, trunc)
        self._vbg.integrate(blocks, img, colour, self._K, self._K, ext, 1.0, self.max_range, trunc)
        if classes is None or self.n_classes == 0:
            return
        c = np.asarray(classes, np.int64)
        ok = (d > 0) & (c >= 0) & (c < self.n_classes)
        if not np.any(ok):
            return
        pts = self._dirs[ok] * d[ok][:, None].astype(np.float64)
        world = pts @ T[:3, :3].T + T[:3, 3]
        keys = pack_keys(point_to_index(world, self.h))
        self._add_votes(keys, c[ok], np.ones(len(keys), np.int64))

    # -- votes ------------------------------------------------------------------------------------
    def _add_votes(self, keys, cls, cnt) -> None:
        self._keys.append(keys)
        self._cls.append(cls)
        self._cnt.append(cnt)
        self._pending += len(keys)
        if self._pending > _COMPACT_EVERY:
            self._compact()

    def _compact(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if not self._keys:
            z = np.zeros(0, np.int64)
            return z, z, z
        k, c, n = (np.concatenate(a) for a in (self._keys, self._cls, self._cnt))
        o = np.lexsort((c, k))
        k, c, n = k[o], c[o], n[o]
        start = np.r_[True, (k[1:] != k[:-1]) | (c[1:] != c[:-1])] if len(k) else np.zeros(0, bool)
        idx = np.flatnonzero(start)
        k, c, n = k[idx], c[idx], np.add.reduceat(n, idx) if len(idx) else n[:0]
        self._keys, self._cls, self._cnt, self._pending = [k], [c], [n], len(k)
        return k, c, n

    def vote_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Voxels with votes and their votes: keys (v,) int64 sorted, counts (v, C) int64."""
        k, c, n = self._compact()
        vkeys, inv = np.unique(k, return_inverse=True)
        table = np.zeros((len(vkeys), max(self.n_classes, 1)), np.int64)
        np.add.at(table, (inv, c), n)
        return vkeys, table

    # -- read-out ---------------------------------------------------------------------------------
    def occupied_and_free(self) -> tuple[np.ndarray, np.ndarray]:
        """Sorted int64 keys of the occupied and the free voxels (module docstring)."""
        h = self.h
        if self._vbg.hashmap().size() == 0:  # no valid depth ever (Open3D refuses to extract from an empty grid)
            z = np.zeros(0, np.int64)
            return z, z
        pcd = self._vbg.extract_point_cloud(weight_threshold=self.weight_threshold)
        pts = pcd.point.positions.numpy().astype(np.float64) if "positions" in pcd.point else np.zeros((0, 3))
        occ = np.unique(pack_keys(np.floor(pts / h + 0.5).astype(np.int64))) if len(pts) else np.zeros(0, np.int64)
        hm = self._vbg.hashmap()
        active = hm.active_buf_indices()
        coords, flat = self._vbg.voxel_coordinates_and_flattened_indices(active)
        tsdf = self._vbg.attribute("tsdf").reshape((-1,))[flat].numpy()
        weight = self._vbg.attribute("weight").reshape((-1,))[flat].numpy()
        seen = (weight >= self.weight_threshold) & (tsdf > 0)
        free = np.unique(pack_keys(np.round(coords.numpy()[seen].astype(np.float64) / h).astype(np.int64)))
        free = np.setdiff1d(free, occ, assume_unique=True)
        return occ, free

    def label_keys(self, occ_keys: np.ndarray) -> np.ndarray:
        """Class id (n,) int64 of occupied voxels ``occ_keys`` (-1: no class): votes in the voxel, else its 26
        neighbours' (module docstring)."""
        occ_keys = np.asarray(occ_keys, np.int64)
        out = np.full(len(occ_keys), -1, np.int64)
        if self.n_classes == 0 or len(occ_keys) == 0:
            return out
        vkeys, table = self.vote_table()
        if len(vkeys) == 0:
            return out

        def lookup(keys):
            pos = np.clip(np.searchsorted(vkeys, keys), 0, len(vkeys) - 1)
            hit = vkeys[pos] == keys
            v = np.zeros((len(keys), table.shape[1]), np.int64)
            v[hit] = table[pos[hit]]
            return v

        own = lookup(occ_keys)
        has = own.sum(1) > 0
        out[has] = own[has].argmax(1)
        rest = np.flatnonzero(~has)
        if len(rest):
            ijk = unpack_keys(occ_keys[rest])
            near = np.zeros((len(rest), table.shape[1]), np.int64)
            for off in _NEIGHBOURS:
                near += lookup(pack_keys(ijk + off))
            got = near.sum(1) > 0
            out[rest[got]] = near[got].argmax(1)
        return out

    def grid(self, vocab) -> Grid:
        """The stream's grid: classes 1..C (``class_names = ["empty"] + vocab``), 254 occupied without class,
        0 free, 255 unobserved, over the box of the occupied and free voxels."""
        occ, free = self.occupied_and_free()
        cls = self.label_keys(occ)
        occ_labels = np.where(cls >= 0, cls + 1, OCCUPIED_UNKNOWN_CLASS)
        return keys_to_grid(np.r_[occ, free], np.r_[occ_labels, np.full(len(free), EMPTY)], self.h,
                            ["empty"] + list(vocab))


def keys_to_grid(keys: np.ndarray, labels: np.ndarray, voxel_size: float, class_names) -> Grid:
    """A grid over the box of ``keys`` (n,) int64 with ``labels`` (n,) there and 255 elsewhere (an empty set:
    one unobserved voxel at the origin, as the mapper's export)."""
    keys = np.asarray(keys, np.int64)
    if len(keys) == 0:
        return Grid(np.full((1, 1, 1), UNKNOWN, np.uint8), index_to_center(np.zeros(3, np.int64), voxel_size),
                    voxel_size, list(class_names))
    idx = unpack_keys(keys)
    i0 = idx.min(axis=0)
    lab = np.full(tuple(idx.max(axis=0) - i0 + 1), UNKNOWN, np.uint8)
    lab[tuple((idx - i0).T)] = np.asarray(labels).astype(np.uint8)
    return Grid(lab, index_to_center(i0, voxel_size), voxel_size, list(class_names))
