"""Learned branch segmentation from RGB (+ optical flow): network, weights, loading.

No pybullet or branch_gym import: the segmenter runs on real camera frames. Training data and
the training loop live in ``branch_gym.segmenter_training`` (they need the simulator).
"""

from recon.segmentation.inputs import FlowConfig, dis_flow, make_input, normalise_flow
from recon.segmentation.metrics import mask_iou, pooled_iou
from recon.segmentation.network import SegmenterNet, SegmenterNetConfig, count_parameters
from recon.segmentation.segmenter import (
    LearnedSegmenter,
    default_weights_path,
    fuse_batch_norm,
    load_segmenter,
)
from recon.segmentation.weights import SegmenterWeightsError, load_weights, save_weights

__all__ = [
    "FlowConfig",
    "LearnedSegmenter",
    "SegmenterNet",
    "SegmenterNetConfig",
    "SegmenterWeightsError",
    "count_parameters",
    "default_weights_path",
    "dis_flow",
    "fuse_batch_norm",
    "load_segmenter",
    "load_weights",
    "make_input",
    "mask_iou",
    "normalise_flow",
    "pooled_iou",
    "save_weights",
]
