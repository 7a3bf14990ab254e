"""Learned branch segmentation from RGB (+ optical flow): network, weights, loading.

No pybullet or branch_gym import: the segmenter runs on real camera frames. Training data and
the training loop live in ``branch_gym.segmenter_training`` (they need the simulator).

The names below load their module on first use (PEP 562), so that ``recon.segmentation.flow``
(OpenCV and numpy only) is importable without torch.
"""

import importlib

# Public name -> the submodule that defines it.
_EXPORTS = {
    "FlowConfig": "inputs",
    "dis_flow": "inputs",
    "make_input": "inputs",
    "normalise_flow": "inputs",
    "mask_iou": "metrics",
    "pooled_iou": "metrics",
    "SegmenterNet": "network",
    "SegmenterNetConfig": "network",
    "count_parameters": "network",
    "LearnedSegmenter": "segmenter",
    "default_weights_path": "spec",
    "fuse_batch_norm": "segmenter",
    "load_segmenter": "segmenter",
    "SegmenterWeightsError": "weights",
    "load_weights": "weights",
    "save_weights": "weights",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
