"""Hardware-agnostic 3D branch reconstruction from RGB frames, masks and camera poses.

Nothing in this package imports pybullet or branch_gym: it runs on recorded real-robot data.
"""

from recon.camera import CameraIntrinsics
from recon.frame import Frame
from recon.model import BranchModel, TreeModel

__all__ = ["BranchModel", "CameraIntrinsics", "Frame", "TreeModel"]
