"""The spill thinning (issue 22, docs/mapping.md step 6): a surface that pose error smeared over a voxel face
resolves to the side most of the evidence supports; a genuinely two-voxel-thick wall, a plane tied on a face
and a voxel a surface only clips are kept; the decision is the same whole or a slab at a time; maps made
before it export as they were made."""

import dataclasses
import json

import numpy as np
import pytest
from map_helpers import random_semantic_channels, sorted_scene

import panovocc_cli.mapping.export as export
from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.lattice import pack_keys, unpack_keys
from panovocc_cli.mapping.export import OccupiedChannels, decide, export_memory, memory_to_grid
from panovocc_cli.mapping.memory import FIXED_SCALE, GEOMETRY_NAMES, Delta, NonzeroChannels, VoxelMemory
from panovocc_cli.mapping.params import OccupancyParams

ON = OccupancyParams(spill=0.3)
OBS = 50  # frames that observed every voxel here


def _layer(axis: int, at: int, span=range(0, 6), offset=(0, 0, 0)) -> np.ndarray:
    """Voxel indices (n, 3) of a square sheet normal to ``axis`` at index ``at``."""
    u, v = np.meshgrid(np.asarray(span), np.asarray(span), indexing="ij")
    cols = [u.ravel(), v.ravel()]
    cols.insert(axis, np.full(u.size, at))
    return np.stack(cols, 1) + np.asarray(offset)


def _rows(idx, hits, per_hit, free=0):
    """Channels of voxels ``idx`` hit in ``hits`` of OBS frames, each hit bringing ``per_hit`` support, and
    seen free ``free`` times."""
    n = len(idx)
    return {"A": np.full((n, 1), int(round(hits * per_hit * FIXED_SCALE)), np.int64),
            "N": np.full((n, 1), hits, np.int64), "F": np.full((n, 1), free, np.int64),
            "O": np.full((n, 1), OBS, np.int64)}


def _scene():
    """Sorted keys, channels and named voxel sets of a hand-made memory:

    * ``smear``: a plane normal to x, its surface in layer x=8 (40 of 50 frames hit it), spilled into x=7 by
      pose error (8 frames: whole surface patches, the same support per hit), seen free at x=6 (and nothing
      at x=9: unobserved behind the surface);
    * ``thick``: a wall two voxels thick normal to y (y=20, 21, both hit in 40 frames), free on both sides;
    * ``tie``: a plane on the face between z=30 and z=31 (both hit in 40 frames, half the support each);
    * ``clip``: beside a surface layer (x=60), a layer a surface only clips (x=59: 8 hits of a tenth the
      support each), free beyond;
    * ``between``: a spill between two surfaces 2 voxels apart (x=80, 82 hit in 40 frames, x=81 in 8).
    """
    parts = {
        "smear_surface": (_layer(0, 8), 40, 0.5, 0), "smear": (_layer(0, 7), 8, 0.5, 0), "smear_free": (_layer(0, 6), 0, 0, 20),
        "thick": (np.concatenate([_layer(1, 20, offset=(30, 0, 0)), _layer(1, 21, offset=(30, 0, 0))]), 40, 0.5, 0),
        "thick_free": (np.concatenate([_layer(1, 19, offset=(30, 0, 0)), _layer(1, 22, offset=(30, 0, 0))]), 0, 0, 20),
        "tie": (np.concatenate([_layer(2, 30, offset=(40, 0, 0)), _layer(2, 31, offset=(40, 0, 0))]), 40, 0.25, 0),
        "tie_free": (np.concatenate([_layer(2, 29, offset=(40, 0, 0)), _layer(2, 32, offset=(40, 0, 0))]), 0, 0, 20),
        "clip_surface": (_layer(0, 60), 40, 0.5, 0), "clip": (_layer(0, 59), 8, 0.05, 0), "clip_free": (_layer(0, 58), 0, 0, 20),
        "between_surfaces": (np.concatenate([_layer(0, 80), _layer(0, 82)]), 40, 0.5, 0), "between": (_layer(0, 81), 8, 0.5, 0),
    }
    keys, ch, sets = [], {k: [] for k in GEOMETRY_NAMES}, {}
    for name, (idx, hits, per_hit, free) in parts.items():
        k = pack_keys(idx)
        sets[name] = k
        keys.append(k)
        for c, v in _rows(idx, hits, per_hit, free).items():
            ch[c].append(v)
    return sorted_scene(keys, ch, sets)


def _occupied(keys, ch, p):
    _, occ_keys = memory_to_grid(keys, ch, 0.08, p)
    return set(occ_keys.tolist())


def test_a_smeared_plane_is_thinned_and_genuine_pairs_are_kept():
    keys, ch, sets = _scene()
    before, after = _occupied(keys, ch, OccupancyParams()), _occupied(keys, ch, ON)
    every = lambda name, s: set(sets[name].tolist()) <= s  # noqa: E731
    none = lambda name, s: not (set(sets[name].tolist()) & s)  # noqa: E731
    # the base rule (N/O >= 0.06) keeps every spill: the surfaces come out two voxels thick
    assert all(every(n, before) for n in ("smear", "smear_surface", "thick", "tie", "clip", "between"))
    # the thinning takes the spills and only them
    assert none("smear", after) and none("between", after)
    assert every("smear_surface", after) and every("between_surfaces", after)
    assert every("thick", after) and every("tie", after) and every("clip", after) and every("clip_surface", after)
    assert before - after == set(sets["smear"].tolist()) | set(sets["between"].tolist())


def test_each_condition_of_the_thinning_is_needed():
    """A spill with an occupied voxel beyond it that is no stronger (a smear three voxels thick), one holding
    a third of the surface's share, or one whose hits bring a tenth of the surface's support each (a
    surface only clips it) is kept; so is every spill with ``spill = 0``."""
    keys, ch, sets = _scene()
    smear = np.isin(keys, sets["smear"])
    beyond = np.isin(keys, sets["smear_free"])
    ch2 = {c: v.copy() for c, v in ch.items()}
    ch2["N"][beyond], ch2["A"][beyond] = 8, int(8 * 0.5 * FIXED_SCALE)  # x=6 occupied like x=7
    assert set(sets["smear"].tolist()) <= _occupied(keys, ch2, ON)
    ch3 = {c: v.copy() for c, v in ch.items()}
    ch3["N"][smear], ch3["A"][smear] = 14, int(14 * 0.5 * FIXED_SCALE)  # 14/40 = 0.35 of the surface's share
    assert set(sets["smear"].tolist()) <= _occupied(keys, ch3, ON)
    ch4 = {c: v.copy() for c, v in ch.items()}
    ch4["A"][smear] = int(8 * 0.05 * FIXED_SCALE)
    assert set(sets["smear"].tolist()) <= _occupied(keys, ch4, ON)
    assert _occupied(keys, ch, dataclasses.replace(ON, spill=0.0)) == _occupied(keys, ch, OccupancyParams())
    # the same scene with its axes permuted and mirrored: the same voxels thinned
    gone = np.setdiff1d(keys[ch["N"][:, 0] > 0], sorted(_occupied(keys, ch, ON)))
    assert len(gone) == len(sets["smear"]) + len(sets["between"])
    for perm, sign in (((0, 1, 2), (-1, 1, 1)), ((1, 2, 0), (1, -1, 1)), ((2, 0, 1), (1, 1, -1))):
        moved = lambda k: pack_keys(unpack_keys(k)[:, list(perm)] * np.asarray(sign))  # noqa: E731
        k2 = moved(keys)
        order = np.argsort(k2)
        ch2 = {c: v[order] for c, v in ch.items()}
        gone2 = np.setdiff1d(k2[order][ch2["N"][:, 0] > 0], sorted(_occupied(k2[order], ch2, ON)))
        assert np.array_equal(np.sort(moved(gone)), gone2)


def _memory(keys, ch) -> VoxelMemory:
    mem = VoxelMemory(0.08)
    mem.add(Delta(keys, ch))
    return mem


def test_slab_by_slab_export_equals_the_whole(monkeypatch):
    """The mapper's export (a slab of the key space at a time, neighbours read by key from the memory) gives
    the whole-memory export's grid bit for bit, with slabs and slices that cut the smeared pair apart."""
    keys, ch, sets = _scene()
    rng = np.random.default_rng(0)  # and random voxels around them: every kind of decision
    extra = np.unique(pack_keys(rng.integers(0, 90, (4000, 3))))
    extra = extra[~np.isin(extra, keys)]
    hits = rng.integers(0, 50, len(extra))
    ex = {"A": (hits * rng.uniform(0.05, 0.6, len(extra)) * FIXED_SCALE).astype(np.int64)[:, None],
          "N": hits[:, None], "F": rng.integers(0, 3, len(extra))[:, None], "O": np.full((len(extra), 1), OBS)}
    keys = np.concatenate([keys, extra])
    order = np.argsort(keys)
    keys = keys[order]
    ch = {c: np.concatenate([ch[c], ex[c]])[order] for c in GEOMETRY_NAMES}
    whole = export_memory(keys, ch, 0.08, ON)
    mem = _memory(keys, ch)
    monkeypatch.setattr(export, "CHUNK", 97)  # slices that cut through each sheet
    slabs = list(mem.nonzero_slabs(max_voxels=1))  # one block x-index (8 voxels) a slab: x=7 | x=8 cut
    assert len(slabs) > 5
    pieces = (lambda: ((k, NonzeroChannels(mem, loc), loc) for k, loc in mem.nonzero_slabs(max_voxels=1)))
    reader = (lambda loc: OccupiedChannels(NonzeroChannels(mem, loc), np.arange(len(loc))))
    sliced = export_memory(None, None, 0.08, ON, pieces=pieces, reader=reader,
                           lookup=lambda k: mem.gather(k, GEOMETRY_NAMES))
    assert np.array_equal(whole.occupied_keys, sliced.occupied_keys)
    assert whole.grid.labels.tobytes() == sliced.grid.labels.tobytes()
    assert np.allclose(whole.grid.origin, sliced.grid.origin)
    assert not np.isin(sets["smear"], whole.occupied_keys).any()
    assert np.isin(sets["smear_surface"], whole.occupied_keys).all()
    off = export_memory(keys, ch, 0.08, OccupancyParams())
    assert len(off.occupied_keys) > len(whole.occupied_keys)


def test_thinning_needs_the_neighbours_and_is_off_by_default():
    keys, ch, _ = _scene()
    assert OccupancyParams().spill == 0
    with pytest.raises(PanovoccError, match="neighbours"):
        decide(keys, ch, ON)  # no lookup
    occ, free, g = decide(keys, ch, OccupancyParams())
    ref = export.classify(ch["A"], ch["N"], ch["F"], ch["O"], OccupancyParams())
    assert all(np.array_equal(a, b) for a, b in zip((occ, free, g), ref))


def test_a_map_made_before_the_thinning_exports_without_it(tmp_path):
    """config.json without the ``spill`` key (a map made before the rule): read with spill 0, whatever the
    default; with the key, its value."""
    from panovocc_cli.mapping.config import _read_sections
    from panovocc_cli.mapping.params import GeometryParams

    d = {"format_version": 1, "geometry": dataclasses.asdict(GeometryParams()),
         "occupancy": {k: v for k, v in dataclasses.asdict(OccupancyParams(spill=0.3)).items() if k != "spill"}}
    _, o, _, _ = _read_sections(json.loads(json.dumps(d)), tmp_path / "config.json")
    assert o.spill == 0.0
    d["occupancy"]["spill"] = 0.3
    _, o, _, _ = _read_sections(d, tmp_path / "config.json")
    assert o.spill == 0.3


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_incremental_export_with_the_thinning_equals_a_full_one(monkeypatch, seed):
    """A voxel's thinning reads its face neighbours, so a change at one voxel can thin or restore the next:
    the incremental export (previous grid + changed keys) still equals the full one bit for bit."""
    monkeypatch.setattr(export, "BLOCK", 4)
    keys, ch, sets = _scene()
    n = len(keys)
    ch, vocab, sem = random_semantic_channels(ch, n, seed)
    rng = np.random.default_rng(seed + 100)
    before = export_memory(keys, ch, 0.08, ON, vocab, sem)
    # the surface layers lose support at a few voxels: the spill beside them is no longer thinned
    surf = np.flatnonzero(np.isin(keys, np.concatenate([sets["smear_surface"], sets["between_surfaces"]])))
    pick = rng.choice(surf, 6, replace=False)
    ch2 = {c: v.copy() for c, v in ch.items()}
    ch2["A"][pick] //= 4
    full = export_memory(keys, ch2, 0.08, ON, vocab, sem)
    assert not np.array_equal(full.occupied_keys, before.occupied_keys)  # the thinning changed elsewhere
    inc = export_memory(keys, ch2, 0.08, ON, vocab, sem, previous=before.grid, changed_keys=keys[pick])
    assert np.array_equal(inc.occupied_keys, full.occupied_keys)
    assert inc.grid.labels.tobytes() == full.grid.labels.tobytes()


def test_incremental_export_relabels_around_a_voxel_thinned_by_its_neighbours_change(monkeypatch):
    """A spill thinned because its surface neighbour gained support is not itself a changed voxel; a voxel
    that took its label (nearest-evidence transfer) in a cube whose halo does not reach the changed surface
    is still labelled again (the changed keys' face neighbours count as changed)."""
    from types import SimpleNamespace

    from panovocc_cli.semantics.gsc import GSCParams

    monkeypatch.setattr(export, "BLOCK", 7)  # cube [0, 7) in x: its halo of 1 reaches x = 7, not x = 8
    surface, spill, lone = _layer(0, 8), _layer(0, 7), np.array([[6, 6, 2]])
    idx = np.concatenate([surface, spill, lone])
    keys = pack_keys(idx)
    order = np.argsort(keys)
    n = len(keys)
    ch = {c: np.concatenate([v1, v2, v3])[order] for c, v1, v2, v3 in
          ((c, _rows(surface, 8, 0.5)[c], _rows(spill, 8, 0.5)[c], _rows(lone, 8, 0.5)[c]) for c in GEOMETRY_NAMES)}
    keys = keys[order]
    is_lone = keys == pack_keys(lone)[0]
    E = np.zeros((n, 2), np.int64)
    E[:, 0] = 100
    E[is_lone] = 0  # the lone voxel has no evidence: it takes the nearest spill voxel's class
    ch.update(E=E, S=np.where(is_lone, 0, 100)[:, None], normal_sum=np.zeros((n, 3), np.int64),
              rgb_sum=np.zeros((n, 3), np.int64), count=np.ones((n, 1), np.int64))
    sem = SimpleNamespace(use_gsc=False, gsc=GSCParams(max_dist_vox=1.5))
    before = export_memory(keys, ch, 0.08, ON, ["wall", "floor"], sem)
    lone_key = pack_keys(lone)[0]
    assert before.labels[np.searchsorted(before.occupied_keys, lone_key)] == 0  # the spill's class
    changed = keys[np.isin(keys, pack_keys(surface))]
    ch2 = {c: v.copy() for c, v in ch.items()}
    at = np.isin(keys, changed)
    ch2["N"][at], ch2["A"][at] = 40, int(40 * 0.5 * FIXED_SCALE)  # the surface's share now 5 times the spill's
    full = export_memory(keys, ch2, 0.08, ON, ["wall", "floor"], sem)
    assert not np.isin(pack_keys(spill), full.occupied_keys).any()  # thinned
    assert full.labels[np.searchsorted(full.occupied_keys, lone_key)] == -1
    inc = export_memory(keys, ch2, 0.08, ON, ["wall", "floor"], sem, previous=before.grid, changed_keys=changed)
    assert np.array_equal(inc.labels, full.labels)
    assert inc.grid.labels.tobytes() == full.grid.labels.tobytes()
