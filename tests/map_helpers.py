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
