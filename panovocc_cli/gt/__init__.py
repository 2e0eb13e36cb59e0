"""Ground truth on the global lattice: from a mesh (:mod:`.mesh`, exact surface voxelisation) or lifted from a
capture's depth and sparse annotations (:mod:`.consensus` the occupancy, :mod:`.lifted` the labels, the Pan-Holo360D protocol); :mod:`.run` reads and
writes around both (``panovocc gt``)."""

from ..gt_config import GtConfig, LiftParams
from .consensus import ConsensusLift
from .lifted import depth_bounds, parse_annotated
from .mesh import check_gt_memory, gt_memory_estimate, voxelize_scene
from .run import accumulate_sequence, lift_sequence, run_gt, run_lifted_gt, run_mesh_gt

__all__ = ["GtConfig", "LiftParams", "ConsensusLift", "depth_bounds", "parse_annotated", "check_gt_memory",
           "gt_memory_estimate", "voxelize_scene", "accumulate_sequence", "lift_sequence", "run_gt", "run_lifted_gt", "run_mesh_gt"]
