"""The surface-offset channel P and the face resolution (issue 22, docs/mapping.md steps 4 and 6): each frame's
mean measured position and normal per voxel, summed exactly; a surface that pose error smeared over a voxel
face resolves to the side its mean position lies on; a thin wall seen from both sides, a tie, an oblique
surface and a wall two voxels thick are kept; the decision is the same whole or a slab at a time; maps
without the channel export as they were made."""

import dataclasses
import json

import numpy as np
import pytest
from box_room import box_depth
from map_helpers import random_semantic_channels, sorted_scene

import panovocc_cli.mapping.export as export
from panovocc_cli.geometry.lattice import index_to_center, pack_keys, unpack_keys
from panovocc_cli.mapping.contributors import geometry_delta, geometry_parts
from panovocc_cli.mapping.export import OccupiedChannels, export_memory, memory_to_grid
from panovocc_cli.mapping.memory import (FIXED_SCALE, GEOMETRY_CHANNELS, GEOMETRY_NAMES, OFFSET_CHANNEL, Delta,
                                         NonzeroChannels, VoxelMemory)
from panovocc_cli.mapping.params import GeometryParams, OccupancyParams
from panovocc_cli.mapping.psvf.update import NORMAL_UNIT, OFFSET_STEPS

ON = OccupancyParams(resolve=True)
OBS = 50  # frames that observed every voxel here
H = 0.08


def test_offset_channel_holds_each_frames_mean_position_and_normal():
    """A box room with walls off the lattice's planes: in a voxel a wall passes through, P's mean offset
    along the wall's normal is the wall's distance from the voxel centre and its mean normal points at the
    camera; the channel exists only where a measurement fell, and the A N F O part is geometry_delta's."""
    lo, hi = np.array([-1.97, -1.45, -1.21]), np.array([2.01, 1.53, 1.57])
    T = np.eye(4)
    depth = box_depth(256, T, lo, hi)
    p = GeometryParams(voxel_size=H, stride=1, offsets=True)
    geo, off = geometry_parts(depth, T, p)
    ref = geometry_delta(depth, T, p)
    assert np.array_equal(geo.keys, ref.keys) and all(np.array_equal(geo.channels[k], ref.channels[k]) for k in "ANFO")
    P = off.channels["P"]
    assert set(off.channels) == {"P"} and P.shape == (len(off), OFFSET_CHANNEL.width)
    assert np.all(np.diff(off.keys) > 0) and np.all(P[:, 0] == 1) and np.array_equal(P[:, 7:10], P[:, 1:4] ** 2)
    assert np.isin(off.keys, geo.keys).all()
    assert len(geometry_parts(depth, T, dataclasses.replace(p, offsets=False))) == 1
    assert GeometryParams().offsets is False  # recorded only when asked for (or with --resolve)
    c = index_to_center(unpack_keys(off.keys), H)
    q = P[:, 1:4] / OFFSET_STEPS * H  # mean offset, metres
    n = P[:, 4:7] / NORMAL_UNIT
    for axis, wall, inward in ((0, hi[0], -1), (1, lo[1], 1), (2, hi[2], -1)):
        others = [a for a in range(3) if a != axis]
        away = np.all(np.abs(c[:, others]) < np.abs(np.stack([lo, hi])[:, others]).min(0) - 0.3, axis=1)
        on = away & (np.abs(c[:, axis] - wall) < H / 2)
        assert on.sum() > 50
        np.testing.assert_allclose(c[on, axis] + q[on, axis], wall, atol=H / OFFSET_STEPS)  # the wall's place
        assert np.all(n[on, axis] * inward > 0.97)  # towards the camera inside the room


def _layer(axis: int, at: int, span=range(0, 6), offset=(0, 0, 0)) -> np.ndarray:
    u, v = np.meshgrid(np.asarray(span), np.asarray(span), indexing="ij")
    cols = [u.ravel(), v.ravel()]
    cols.insert(axis, np.full(u.size, at))
    return np.stack(cols, 1) + np.asarray(offset)


def _rows(idx, hits, axis, offset, normal, spread=400, free=0):
    """Channels of voxels ``idx`` hit in ``hits`` of OBS frames (support 0.5 a hit), each frame's
    measurements at ``offset`` voxel edges from the centre along ``axis`` on average with their mean normal
    ``normal`` along it (the other components 0), the frames' mean offsets varying by ``spread`` squared
    steps (1/OFFSET_STEPS) about it."""
    n = len(idx)
    P = np.zeros((n, OFFSET_CHANNEL.width), np.int64)
    q = int(round(offset * OFFSET_STEPS))
    P[:, 0] = hits
    P[:, 1 + axis] = hits * q
    P[:, 4 + axis] = int(round(hits * normal * NORMAL_UNIT))
    P[:, 7 + axis] = hits * (q * q + spread)
    return {"A": np.full((n, 1), int(round(hits * 0.5 * FIXED_SCALE)), np.int64),
            "N": np.full((n, 1), hits, np.int64), "F": np.full((n, 1), free, np.int64),
            "O": np.full((n, 1), OBS, np.int64), "P": P}


def _scene():
    """Sorted keys, channels and named voxel sets of a hand-made memory:

    * ``smear``: a plane normal to x a few mm inside x=8 near its face with x=7, seen from one side, 40
      frames in x=8, 12 frames in x=7 (pose error), both near the shared face;
    * ``smear_z``: the same normal to z, the surface in z=31 (the spill below, z=30, holds 15 frames);
    * ``thin``: a thin wall on the face y=20|21, seen from both sides (opposite sides): both kept;
    * ``tie``: a plane on the face x=40|41, its mean position exactly on the face: both kept;
    * ``mixed``: like ``smear`` with a mean normal of 0.6 along x (an oblique surface, or one seen from both
      sides): kept;
    * ``thick``: a wall two voxels thick: its front in x=60 near the centre, its back in x=61 without a
      measurement (P = 0): kept.
    """
    parts = {
        "smear_surface": (_layer(0, 8), 40, 0, -0.35, 1), "smear": (_layer(0, 7), 12, 0, 0.4, 1),
        "smear_z_surface": (_layer(2, 31, offset=(20, 20, 0)), 40, 2, -0.3, -1),
        "smear_z": (_layer(2, 30, offset=(20, 20, 0)), 15, 2, 0.42, -1),
        "thin_a": (_layer(1, 20, offset=(30, 0, 0)), 30, 1, 0.4, -1),
        "thin_b": (_layer(1, 21, offset=(30, 0, 0)), 30, 1, -0.4, 1),
        "tie_a": (_layer(0, 40), 20, 0, 0.45, 1), "tie_b": (_layer(0, 41), 20, 0, -0.45, 1),
        "mixed_surface": (_layer(0, 50), 40, 0, -0.35, 0.6), "mixed": (_layer(0, 49), 12, 0, 0.4, 0.6),
        "thick_front": (_layer(0, 60), 40, 0, 0.05, 1), "thick_back": (_layer(0, 61), 10, 0, 0.0, 0),
    }
    keys, ch, sets = [], {k: [] for k in GEOMETRY_NAMES + ("P",)}, {}
    for name, (idx, hits, axis, off, side) in parts.items():
        k = pack_keys(idx)
        sets[name] = k
        keys.append(k)
        rows = _rows(idx, hits, axis, off, side)
        if name == "thick_back":
            rows["P"][:] = 0
        for c, v in rows.items():
            ch[c].append(v)
    return sorted_scene(keys, ch, sets)


def _occupied(keys, ch, p):
    return set(memory_to_grid(keys, ch, H, p)[1].tolist())


def test_a_smeared_plane_resolves_to_its_side_and_genuine_pairs_are_kept():
    keys, ch, sets = _scene()
    before, after = _occupied(keys, ch, OccupancyParams()), _occupied(keys, ch, ON)
    assert before == set(keys.tolist())  # the base rule keeps every voxel here
    gone = set(sets["smear"].tolist()) | set(sets["smear_z"].tolist())
    assert before - after == gone
    # the mean position decides: with the spill's frames the majority, the surface's voxel goes instead
    ch2 = {c: v.copy() for c, v in ch.items()}
    s = np.isin(keys, sets["smear"])
    ch2["P"][s] *= 8  # 96 frames in x=7 against 40 in x=8: the mean lies in x=7
    ch2["N"][s] = 50
    after2 = _occupied(keys, ch2, ON)
    assert set(sets["smear_surface"].tolist()).isdisjoint(after2) and set(sets["smear"].tolist()) <= after2
    # each condition is needed: offsets pointing away from the face, or a resolve_offset above them, keep it
    assert _occupied(keys, ch, dataclasses.replace(ON, resolve_offset=0.45)) == before
    assert _occupied(keys, ch, dataclasses.replace(ON, resolve_normal=0.5)) == before - gone - set(
        sets["mixed"].tolist())
    assert _occupied(keys, ch, OccupancyParams(resolve=False)) == before
    # two surfaces, each measured at its own place frame after frame (no spread), are not one smeared surface
    ch4 = {c: v.copy() for c, v in ch.items()}
    pair = np.isin(keys, np.concatenate([sets["smear"], sets["smear_surface"]]))
    ch4["P"][pair, 7] = ch4["P"][pair, 1] ** 2 // ch4["P"][pair, 0]  # sum of q^2 = m q^2: variance 0
    assert _occupied(keys, ch4, ON) == before - set(sets["smear_z"].tolist())
    assert _occupied(keys, ch4, dataclasses.replace(ON, resolve_gap=0)) == after
    # without the channel (a map made before it) the rule reads nothing and the export is the base rule's
    no_p = {c: v for c, v in ch.items() if c != "P"}
    assert _occupied(keys, no_p, ON) == before
    # mirrored and permuted axes: the same voxels go
    for perm, sign in (((1, 2, 0), (1, -1, 1)), ((2, 0, 1), (-1, 1, -1))):
        moved = lambda k: pack_keys(unpack_keys(k)[:, list(perm)] * np.asarray(sign))  # noqa: E731
        k2 = moved(keys)
        order = np.argsort(k2)
        ch3 = {c: v[order].copy() for c, v in ch.items()}
        for base, flips in ((1, True), (4, True), (7, False)):  # P's per-axis columns follow the axes
            cols = ch3["P"][:, base:base + 3].copy()
            ch3["P"][:, base:base + 3] = cols[:, list(perm)] * (np.asarray(sign) if flips else 1)
        assert _occupied(k2[order], ch3, ON) == set(moved(np.array(sorted(after))).tolist())



def test_the_cameras_side_loses_only_when_the_mean_is_surely_behind_the_face():
    """resolve_behind 1: of a pair whose mean position lies just behind the shared face (within a standard error
    of it), the voxel on the cameras' side is kept (both stay); the voxel behind loses at any margin, and with
    resolve_behind 0 (the default) the front voxel loses as soon as the mean is behind the face."""
    parts = {"front": (_layer(0, 8), 20, -0.45), "behind": (_layer(0, 7), 22, 0.44)}  # normal +x: cameras at +x
    keys, ch, sets = [], {k: [] for k in GEOMETRY_NAMES + ("P",)}, {}
    for name, (idx, hits, off) in parts.items():
        sets[name] = pack_keys(idx)
        keys.append(sets[name])
        for c, v in _rows(idx, hits, 0, off, 1).items():
            ch[c].append(v)
    keys, ch, sets = sorted_scene(keys, ch, sets)
    front, behind = set(sets["front"].tolist()), set(sets["behind"].tolist())
    margin = dataclasses.replace(ON, resolve_behind=1.0)
    assert OccupancyParams().resolve_behind == 0.0  # off by default
    assert _occupied(keys, ch, OccupancyParams()) == front | behind  # the base rule keeps both
    assert _occupied(keys, ch, margin) == front | behind  # the mean is 0.008 edges behind the face: not sure
    assert _occupied(keys, ch, ON) == behind
    # the mirror image (the mean just inside the front voxel): the voxel behind loses, with or without a margin
    ch2 = {c: v.copy() for c, v in ch.items()}
    b = np.isin(keys, sets["behind"])
    ch2["P"][b] = ch2["P"][b] * 12 // 22  # 12 frames behind: the mean 0.009 edges inside the front voxel
    ch2["N"][b] = 12
    assert _occupied(keys, ch2, margin) == front == _occupied(keys, ch2, ON)

def _memory(keys, ch) -> VoxelMemory:
    mem = VoxelMemory(H, GEOMETRY_CHANNELS + (OFFSET_CHANNEL,))
    geo = {c: ch[c] for c in GEOMETRY_NAMES}
    mem.add(Delta(keys, geo))
    has = np.flatnonzero(np.any(ch["P"] != 0, axis=1))  # P rows only where the channel holds something
    mem.add(Delta(keys[has], {"P": ch["P"][has]}))
    return mem


def test_slab_by_slab_export_equals_the_whole(monkeypatch):
    """The mapper's export (a slab of the key space at a time, neighbours and their P read by key from the
    memory) gives the whole-memory export's grid bit for bit, with slabs and slices that cut the pairs."""
    keys, ch, sets = _scene()
    rng = np.random.default_rng(0)  # random voxels around them: every kind of decision
    extra = np.unique(pack_keys(rng.integers(0, 70, (4000, 3))))
    extra = extra[~np.isin(extra, keys)]
    m = len(extra)
    hits = rng.integers(0, 50, m)
    P = np.zeros((m, OFFSET_CHANNEL.width), np.int64)
    q = rng.integers(-127, 128, (m, 3))
    nrm = rng.normal(size=(m, 3))
    P[:, 0] = hits
    P[:, 1:4] = hits[:, None] * q
    P[:, 4:7] = hits[:, None] * np.rint(nrm / np.linalg.norm(nrm, axis=1, keepdims=True) * NORMAL_UNIT).astype(np.int64)
    P[:, 7:10] = hits[:, None] * (q * q + rng.integers(0, 900, (m, 3)))
    ex = {"A": (hits * 0.5 * FIXED_SCALE).astype(np.int64)[:, None], "N": hits[:, None],
          "F": rng.integers(0, 3, m)[:, None], "O": np.full((m, 1), OBS), "P": P}
    keys = np.concatenate([keys, extra])
    order = np.argsort(keys)
    keys = keys[order]
    ch = {c: np.concatenate([ch[c], ex[c]])[order] for c in ch}
    whole = export_memory(keys, ch, H, ON)
    assert len(whole.occupied_keys) < len(export_memory(keys, ch, H, OccupancyParams()).occupied_keys)
    mem = _memory(keys, ch)
    monkeypatch.setattr(export, "CHUNK", 97)
    assert len(list(mem.nonzero_slabs(max_voxels=1))) > 5
    pieces = (lambda: ((k, NonzeroChannels(mem, loc), loc) for k, loc in mem.nonzero_slabs(max_voxels=1)))
    reader = (lambda loc: OccupiedChannels(NonzeroChannels(mem, loc), np.arange(len(loc))))
    sliced = export_memory(None, None, H, ON, pieces=pieces, reader=reader,
                           lookup=lambda k, names=GEOMETRY_NAMES: mem.gather(k, names))
    assert np.array_equal(whole.occupied_keys, sliced.occupied_keys)
    assert whole.grid.labels.tobytes() == sliced.grid.labels.tobytes()
    assert not np.isin(sets["smear"], whole.occupied_keys).any()


def test_a_map_made_before_the_channel_or_the_rule_reads_without_them(tmp_path):
    from panovocc_cli.mapping.config import _read_sections

    g = {k: v for k, v in dataclasses.asdict(GeometryParams()).items() if k != "offsets"}
    o = {k: v for k, v in dataclasses.asdict(OccupancyParams(resolve=True)).items()
         if k not in ("resolve", "resolve_behind")}
    d = {"format_version": 1, "geometry": g, "occupancy": o}
    g2, o2, _, _ = _read_sections(json.loads(json.dumps(d)), tmp_path / "config.json")
    assert g2.offsets is False and o2.resolve is False
    assert o2.resolve_behind == 0.0  # made before the margin: resolves as it did
    d["geometry"]["offsets"], d["occupancy"]["resolve"] = True, True
    g2, o2, _, _ = _read_sections(d, tmp_path / "config.json")
    assert g2.offsets is True and o2.resolve is True and o2.resolve_behind == 0.0
    d["occupancy"]["resolve_behind"] = 1.0  # a map made with --resolve-behind 1 keeps it
    assert _read_sections(d, tmp_path / "config.json")[1].resolve_behind == 1.0


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("behind", [0.0, 1.0])
def test_incremental_export_with_the_resolution_equals_a_full_one(monkeypatch, seed, behind):
    """A voxel's resolution reads its face neighbours, so a change at one voxel can take or restore the
    next: the incremental export (previous grid + changed keys) equals the full one bit for bit (with the
    cameras' side margin too)."""
    monkeypatch.setattr(export, "BLOCK", 4)
    on = dataclasses.replace(ON, resolve_behind=behind)
    keys, ch, sets = _scene()
    n = len(keys)
    ch, vocab, sem = random_semantic_channels(ch, n, seed)
    rng = np.random.default_rng(seed + 100)
    before = export_memory(keys, ch, H, on, vocab, sem)
    # a few surface voxels lose their evidence of lying near the face: the spill beside them comes back
    surf = np.flatnonzero(np.isin(keys, sets["smear_surface"]))
    pick = rng.choice(surf, 6, replace=False)
    ch2 = {c: v.copy() for c, v in ch.items()}
    ch2["P"][pick, 1] = 0  # their x offsets now at the centre
    full = export_memory(keys, ch2, H, on, vocab, sem)
    assert not np.array_equal(full.occupied_keys, before.occupied_keys)
    inc = export_memory(keys, ch2, H, on, vocab, sem, previous=before.grid, changed_keys=keys[pick])
    assert np.array_equal(inc.occupied_keys, full.occupied_keys)
    assert inc.grid.labels.tobytes() == full.grid.labels.tobytes()


def test_map_with_resolve_records_p_and_a_map_without_it_does_not(tmp_path, capsys):
    """`panovocc map --resolve` records channel P (implied) and exports with the resolution; a default map
    keeps no P (and its config says so), and resolving its memory later changes nothing; revising the
    resolved map back to the same poses leaves its memory bit for bit."""
    from cli_helpers import run_cli
    from room_sequence import write_room_sequence

    from panovocc_cli.mapping.config import MapperConfig
    from panovocc_cli.mapping.pipeline import load_config
    from panovocc_cli.mapquery import open_map

    assert MapperConfig(occupancy=OccupancyParams(resolve=True)).check().geometry.offsets
    seq = tmp_path / "room"
    write_room_sequence(seq, 3, 64, furniture=True)
    code, _, err = run_cli(capsys, ["map", seq, tmp_path / "r", "--resolve", "--segmenter", "none", "--quiet"])
    assert code == 0, err
    cfg = load_config(tmp_path / "r")
    assert cfg.geometry.offsets and cfg.occupancy.resolve
    with np.load(tmp_path / "r" / "memory.npz") as z:
        assert "ch_P" in z and np.asarray(z["ch_P"]).any()
        before = {k: np.asarray(z[k]).copy() for k in z.files}
    code, _, err = run_cli(capsys, ["revise", tmp_path / "r", seq / "poses.txt", "--quiet"])
    assert code == 0, err
    with np.load(tmp_path / "r" / "memory.npz") as z:
        assert all(np.array_equal(before[k], z[k]) for k in z.files)
    code, _, err = run_cli(capsys, ["map", seq, tmp_path / "d", "--segmenter", "none", "--quiet"])
    assert code == 0, err
    assert not load_config(tmp_path / "d").geometry.offsets
    with np.load(tmp_path / "d" / "memory.npz") as z:
        assert "ch_P" not in z
    m = open_map(tmp_path / "d")
    try:
        plain = m.export().grid.labels.tobytes()
        m.config = dataclasses.replace(m.config, occupancy=ON)
        assert m.export().grid.labels.tobytes() == plain  # no P: the rule reads nothing
    finally:
        m.close()
