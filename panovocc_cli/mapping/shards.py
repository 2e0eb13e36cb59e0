"""The memory as an exact sum: partial memories of frame shards, their tree reduction, and merges of maps.

A frame's delta depends only on the frame and its pose, and the memory is the integer sum of the kept
deltas (:mod:`.rpu`). So a sequence cut into shards of frames, each integrated on its own into a partial
memory, gives the sequential map exactly once the partial memories are added, in any order and any
grouping; and two maps of one scene made in one world frame add up to the map of both captures.

* :func:`integrate_shard` -- one shard on a worker: each frame's delta record (the bytes the sequential
  run's delta log holds for it, :func:`.rpu.encode_record`) and the shard's partial memory;
* :func:`encode_partial` / :func:`decode_partial` / :func:`sum_partials` -- a partial memory as compact
  bytes (the delta record layout of :mod:`panovocc_cli.io.mapstore`: smallest integer types, sparse rows,
  one Zstandard frame) and the sum of several;
* :func:`merge_configs` -- whether maps can be added (same mapping parameters, vocabulary and origin).

No file is read or written here: frames come from a callable, records and partial memories as bytes.
The Dask driver is :mod:`panovocc_cli.benchmark.sharded`, the merge command's run loop
:func:`panovocc_cli.mapping.pipeline.run_merge`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple, Sequence

import numpy as np

from ..errors import PanovoccError
from ..frame import Frame
from ..io import mapstore
from .config import MapperConfig
from .memory import GEOMETRY_NAMES, Delta, FrameDelta, VoxelMemory
from .rpu import encode_record, memory_specs


class ShardRecords(NamedTuple):
    """What a shard sends back for the delta log: frame ids (ascending), the poses their deltas were
    computed under (k, 4, 4) float64, each frame's PUT payload, and the ids of frames whose delta is empty."""

    ids: list
    poses: np.ndarray
    payloads: list
    empty: list

    def nbytes(self) -> int:
        return int(sum(len(p) for p in self.payloads) + self.poses.nbytes + 8 * len(self.ids))


def shard_ranges(ids: Sequence[int], shards: int) -> list[list[int]]:
    """``ids`` cut into ``shards`` contiguous runs of near-equal length, in order (fewer when there are fewer
    frames; none for no frames)."""
    ids = [int(i) for i in ids]
    k = max(1, min(int(shards), len(ids)))
    cuts = [len(ids) * j // k for j in range(k + 1)]
    return [ids[a:b] for a, b in zip(cuts, cuts[1:]) if b > a]


def integrate_shard(config: MapperConfig, frames: Callable[[int], Frame], ids: Sequence[int],
                    after_frame: Callable[[int], None] | None = None) -> tuple[ShardRecords, bytes]:
    """Integrate frames ``ids`` (``frames(i) -> Frame``, segmented) into a partial memory.

    Returns the shard's :class:`ShardRecords` (each payload the bytes a sequential run appends to its delta
    log for that frame) and the partial memory (:func:`encode_partial`: the exact sum of the shard's deltas).
    ``after_frame(k)`` is called after the k-th frame of the shard (a progress or test hook).
    """
    from .mapper import Mapper, memory_channels

    mapper = Mapper(dataclasses.replace(config))
    memory = VoxelMemory(config.geometry.voxel_size, memory_channels(config))
    poses, payloads, empty = [], [], []
    for k, i in enumerate(ids):
        frame = frames(int(i))
        delta = mapper.delta(frame)
        memory.add(delta, +1)
        T = np.asarray(frame.T_world_cam, np.float64)
        payloads.append(encode_record(delta, T))
        poses.append(T)
        if len(delta) == 0:
            empty.append(int(i))
        if after_frame is not None:
            after_frame(k)
    records = ShardRecords([int(i) for i in ids], np.asarray(poses, np.float64).reshape(-1, 4, 4), payloads, empty)
    return records, encode_partial(memory)


def warm_kernels(config: MapperConfig) -> None:
    """Load the memory's compiled kernels in this process (numba's cache: ~0.5 s once a process) by adding and
    taking out one voxel: what a client does before it times a sharded run, whose only memory work is adding
    the root partial memory."""
    from .mapper import memory_channels

    memory = VoxelMemory(config.geometry.voxel_size, memory_channels(config))
    one = {s.name: np.ones((1, s.width), np.int64) for s in memory.specs}
    delta = as_delta(np.zeros(1, np.int64), one)
    memory.add(delta, +1)
    memory.add(delta, -1)


def encode_partial(memory: VoxelMemory) -> bytes:
    """A memory as compact bytes: its non-zero voxels as one delta record (keys as gaps, channels in their
    smallest integer types, semantic channels only on the rows that hold one) with the channel layout."""
    arrays = memory.to_arrays(sparse=True)
    keys = arrays["keys"]
    channels = {s.name: arrays[f"ch_{s.name}"] for s in memory.specs}
    out = mapstore.delta_arrays([(keys, channels)], np.eye(4))
    out["voxel_size"] = np.asarray(arrays["voxel_size"], np.float64).reshape(1)
    for name in ("channel_names", "channel_widths", "channel_kinds"):
        out[name] = np.asarray(arrays[name])
    return mapstore.encode_arrays(out)


def decode_partial(blob: bytes) -> tuple[float, list, FrameDelta]:
    """Inverse of :func:`encode_partial`: (voxel size, channel specs, the memory as a delta,
    :func:`as_delta`)."""
    z = mapstore.decode_arrays(blob)
    keys, ch = mapstore.arrays_record(z).parts[0]
    return float(z["voxel_size"][0]), memory_specs(z), as_delta(keys, ch)


def as_delta(keys: np.ndarray, channels) -> FrameDelta:
    """A memory's non-zero voxels (``keys`` (n,) int64, ``channels`` name -> (n, width) int64) as a delta
    that adds them: the geometry over every voxel, the other channels over the voxels where one is non-zero
    (no semantic row is allocated for a voxel without semantics)."""
    geo = {k: np.asarray(channels[k]) for k in channels if k in GEOMETRY_NAMES}
    rest = {k: np.asarray(channels[k]) for k in channels if k not in GEOMETRY_NAMES}
    parts = [Delta(keys, geo)] if geo else []
    if rest:
        rows = np.flatnonzero(np.any(np.concatenate(list(rest.values()), axis=1) != 0, axis=1))
        parts.append(Delta(keys[rows], {k: v[rows] for k, v in rest.items()}))
    return FrameDelta(tuple(parts))


def memory_delta(memory: VoxelMemory) -> FrameDelta:
    """A memory as a delta that adds it (:func:`as_delta`): what a merge adds for each input map."""
    keys, ch = memory.nonzero()
    return as_delta(np.asarray(keys), {s.name: ch[s.name] for s in memory.specs})


def sum_partials(*blobs: bytes) -> bytes:
    """The exact sum of partial memories (:func:`encode_partial` bytes) as one (a node of the tree
    reduction). A sum past int64 is refused (:class:`PanovoccError`), never wrapped."""
    memory = None
    for blob in blobs:
        h, specs, delta = decode_partial(blob)
        if memory is None:
            memory = VoxelMemory(h, specs)
        elif h != memory.voxel_size or list(specs) != list(memory.specs):
            raise PanovoccError("partial memories of different layouts cannot be added")
        memory.add(delta, +1)
    if memory is None:
        raise ValueError("sum_partials needs at least one partial memory")
    return encode_partial(memory)


# ---------------------------------------------------------------------------------------------
# merges


def merge_configs(configs: Sequence[MapperConfig], names: Sequence[str]) -> MapperConfig:
    """The mapping configuration maps share, or one line naming the first difference (``names``: how the
    maps are called in it). Maps add up only with the same geometry and occupancy parameters, vocabulary
    (same words, same order), semantic weights and GSC, and the same local origin (voxel keys relative to
    one lattice point of one world frame)."""
    first = configs[0]
    fields = [f.name for f in dataclasses.fields(MapperConfig)]
    for cfg, name in zip(configs[1:], names[1:]):
        for f in fields:
            a, b = getattr(first, f), getattr(cfg, f)
            if a == b:
                continue
            if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
                diff = [g.name for g in dataclasses.fields(a) if getattr(a, g.name) != getattr(b, g.name)]
                what = f"{f}.{diff[0]} {getattr(a, diff[0])!r} in {names[0]} but {getattr(b, diff[0])!r}"
            else:
                what = f"{f} {a!r} in {names[0]} but {b!r}"
            hint = (" (map both with the same --origin X,Y,Z, or give --transform/--align to map one into the "
                    "other's frame)" if f == "origin" else "")
            raise PanovoccError(f"maps made with different parameters cannot be added: {what} in {name}{hint}")
    return first
