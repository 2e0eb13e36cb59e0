"""``panovocc merge MAP_A MAP_B ... OUT``: the exact sum of maps, as a map folder like any other.

Maps made with the same mapping parameters, vocabulary and local origin (:func:`.shards.merge_configs`)
add up: OUT's memory is the sum of the inputs' memories, and its delta log holds the inputs' records, byte
for byte, in frame-id order. So the merge of maps of disjoint ``--frames`` ranges of one sequence is the map
of their union, bit for bit (memory, prediction, every record), and it revises and resumes like one.

Frame ids must not collide: maps of one sequence must hold disjoint frames (``--frames`` ranges), and
maps of separate captures (other sequences, whose ids both start at 0) are renumbered with ``renumber``:
each map's ids shifted past the previous maps' last id. A merge of several sequences records them in
``config.json`` (``merged_from``) and is exported, queried and merged again, but not revised or resumed
(a frame id no longer names one sequence's frame: revise the inputs, merge again).

``transform`` (4, 4): the second map's captures were made in another world frame; ``T`` maps its world into
the first map's. Its frames are then integrated again from its sequence under ``T @ pose`` (with the
semantic observations kept in its records: no segmenter runs), in the first map's frame and origin: the
merged memory is what mapping both captures in one world frame gives.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..geometry.poses import check_rigid
from ..io import mapstore
from ..io.atomic import check_outputs
from ..io.sequence import Sequence, read_meta
from .config import MERGED_FROM, MapConfig, several_sequences
from .mapper import Mapper
from .rpu import encode_record
from .shards import memory_delta, merge_configs

def frames_spec(ids) -> str:
    """Frame ids (ascending) as ``--frames`` ranges: ``0:30,40:60``."""
    ids = [int(i) for i in ids]
    runs, start = [], None
    for k, i in enumerate(ids):
        if start is None:
            start = i
        if k + 1 == len(ids) or ids[k + 1] != i + 1:
            runs.append(f"{start}:{i + 1}")
            start = None
    return ",".join(runs)


def run_merge(maps, out, overwrite: bool = False, transform: np.ndarray | None = None, renumber: bool = False,
              progress: bool = True) -> dict:
    """Merge the map folders ``maps`` (two or more) into ``out``; returns a summary (frames, occupied, free,
    [classed], out). Bad input (a map that cannot be read, different parameters, colliding frame ids, an
    existing OUT without ``overwrite``) is refused with one line before anything is written."""
    from .pipeline import _OUTPUTS, _require_deltas, _writer_lock, write_exports

    maps = [Path(m) for m in maps]
    out = Path(out)
    if len(maps) < 2:
        raise PanovoccError("merge needs two or more maps and an output folder: panovocc merge MAP_A MAP_B ... OUT")
    if transform is not None:
        if len(maps) != 2:
            raise PanovoccError("--transform / --align place the second of exactly two maps in the first's world")
        transform = check_rigid(transform, "--transform")
    raws, cfgs = [], []
    for m in maps:
        _require_deltas(m)
        raw = mapstore.read_map_config(m)
        raws.append(raw)
        cfgs.append(MapConfig.from_json(raw, m / mapstore.CONFIG_NAME))
    mcfgs = [c.mapper_config() for c in cfgs]
    if transform is not None and several_sequences(raws[1]):
        raise PanovoccError("--transform / --align integrate the second map's frames again from its sequence; this map "
                            "merges several sequences: transform its inputs instead", maps[1])
    if transform is not None:  # the second map is integrated again in the first's frame and origin
        merge_configs([mcfgs[0], dataclasses.replace(mcfgs[1], origin=mcfgs[0].origin)], [str(m) for m in maps])
    else:
        merge_configs(mcfgs, [str(m) for m in maps])
    check_outputs([(out, "map", True)], overwrite, inputs=maps)
    mappers = []
    try:
        for m in maps:
            mappers.append(Mapper.load(m))
        plan, sources = _plan(maps, cfgs, raws, mappers, renumber)
        made = not (out.exists() or out.is_symlink())
        out.mkdir(parents=True, exist_ok=True)
        try:
            with _writer_lock(out):
                if (out / mapstore.CONFIG_NAME).exists():
                    if not overwrite:
                        raise PanovoccError("already holds a map (use --overwrite to replace it)", out)
                    for name in _OUTPUTS:
                        (out / name).unlink(missing_ok=True)
                    shutil.rmtree(out / mapstore.DELTAS_DIR, ignore_errors=True)
                summary = _write(out, maps, cfgs, mappers, plan, sources, transform, progress, write_exports)
        except BaseException:
            if made:  # nothing half-written: a folder this merge created goes again
                shutil.rmtree(out, ignore_errors=True)
            raise
    finally:
        for m in mappers:
            m.close()
    return summary


def _plan(maps, cfgs, raws, mappers, renumber: bool):
    """[(new id, map index, old id)] in new-id order, and the sources recorded in config.json."""
    plan, sources, offset = [], [], 0
    owner: dict[int, int] = {}
    for k, (m, mp) in enumerate(zip(maps, mappers)):
        ids = mp.frame_ids
        if not ids:
            raise PanovoccError("holds no frames", m)
        shift = offset if renumber else 0
        for i in ids:
            new = i + shift
            if new in owner:
                raise PanovoccError(f"frame {new} is in both {maps[owner[new]]} and {m}: merge maps of disjoint "
                                    "--frames ranges of one capture, or give --renumber for separate captures")
            owner[new] = k
            plan.append((new, k, i))
        offset = max(owner) + 1
        inner = raws[k].get(MERGED_FROM)
        if inner:  # a merge merged again: its own sources, shifted
            sources += [{**s, "first_id": int(s["first_id"]) + shift} for s in inner]
        else:
            sources.append({"map": str(m.resolve()), "seq": cfgs[k].seq, "first_id": shift})
    plan.sort()
    return plan, sources


def _write(out: Path, maps, cfgs, mappers, plan, sources, transform, progress: bool, write_exports) -> dict:
    from tqdm import tqdm

    first = cfgs[0]
    ids = [new for new, _, _ in plan]
    one_seq = not several_sequences({MERGED_FROM: sources})  # ids still the one sequence's indices
    n_seq = read_meta(first.seq).frames if one_seq and Path(first.seq, "meta.json").is_file() else None
    frames = None if n_seq is not None and ids == list(range(n_seq)) else frames_spec(ids)
    cfg = dataclasses.replace(first, out=str(out.resolve()), frames=frames if one_seq else None)
    d = cfg.to_json()
    if not one_seq:
        d[MERGED_FROM] = sources
    mapstore.write_map_config(out, d)
    merged = Mapper(cfgs[0].mapper_config(), folder=out)
    seq_b = None
    if transform is not None:
        from .pipeline import SequenceFrames

        seq_b = SequenceFrames(Sequence(cfgs[1].seq)).read
    bar = tqdm(total=len(plan), desc="merge", unit="frame", file=sys.stderr, disable=not progress)
    try:
        for new, k, old in plan:
            src = mappers[k]
            T = src.pose(old)
            if transform is not None and k == 1:  # integrated again, in the first map's world and origin
                T = transform @ T
                frame = dataclasses.replace(seq_b(old), T_world_cam=T)
                delta = merged.delta(frame, src.observation(old))
                merged.keep_encoded(new, encode_record(delta, T), T, empty=len(delta) == 0)
                merged.add_sum(delta)
            else:
                merged.keep_encoded(new, src.record(old), T)
            bar.update(1)
        bar.close()
        for k, src in enumerate(mappers):
            if transform is None or k == 0:
                merged.add_sum(memory_delta(src.memory))
        ex = merged.export()
        summary = write_exports(out, merged, first.semantic.ply_color, ex)
        del ex
        merged.save(out)
    except BaseException:
        merged._rpu.rollback()
        raise
    finally:
        merged.close()
    summary.update(frames=len(plan), maps=len(maps), out=str(out))
    return summary


def occupied_points(folder) -> np.ndarray:
    """A map folder's occupied voxel centres (n, 3) float64, world metres (its ``prediction.npz``): what
    ``merge --align`` registers."""
    from ..io.grid import read_grid

    g = read_grid(Path(folder) / "prediction.npz")
    ijk = np.argwhere((g.labels > 0) & (g.labels < 255))
    return g.centers(ijk)
