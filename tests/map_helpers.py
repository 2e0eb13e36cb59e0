"""What the mapping tests read back from a map folder, through the public :class:`Mapper` API."""

import numpy as np

from panovocc_cli.mapping import Mapper


def load_memory(out):
    """A map folder's committed state: (VoxelMemory, frames it holds, their poses (n, 4, 4) float64)."""
    mapper = Mapper.load(out)
    try:
        ids = mapper.frame_ids
        poses = np.stack([mapper.pose(i) for i in ids]) if ids else np.zeros((0, 4, 4))
        return mapper.memory, len(ids), poses
    finally:
        mapper.close()


def random_semantic_channels(ch: dict, n: int, seed: int):
    """``ch`` (a hand-made memory's geometry channels over ``n`` keys) with seeded random semantic channels
    (E over three words, S, normals, colours, counts) and the export's semantic settings (GSC on): what the
    incremental-export tests of the neighbour rules (tests/mapping/test_spill.py, test_face_resolve.py) label.
    Returns (channels, vocabulary, semantic settings)."""
    from types import SimpleNamespace

    from panovocc_cli.semantics.gsc import GSCParams

    rng = np.random.default_rng(seed)
    S = rng.integers(1, 5000, n)
    ch = dict(ch, E=(rng.dirichlet(np.ones(3), n) * S[:, None]).astype(np.int64), S=S[:, None],
              normal_sum=rng.integers(-99, 99, (n, 3)), rgb_sum=rng.integers(0, 9000, (n, 3)),
              count=rng.integers(1, 40, (n, 1)))
    return ch, ["wall", "floor", "chair"], SimpleNamespace(use_gsc=True, gsc=GSCParams())


def sorted_scene(keys: list, ch: dict, sets: dict):
    """A hand-made memory built as lists of key arrays and per-channel row arrays, in key order: (keys,
    channels, sets), the keys asserted distinct (tests/mapping/test_spill.py, test_face_resolve.py)."""
    keys = np.concatenate(keys)
    order = np.argsort(keys)
    assert len(np.unique(keys)) == len(keys)
    return keys[order], {c: np.concatenate(v)[order] for c, v in ch.items()}, sets
