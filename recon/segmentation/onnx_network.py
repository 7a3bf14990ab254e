"""The segmenter network run by ONNX Runtime: the fast path of a weights file on a CPU.

A weights file ``NAME.pt`` (:func:`recon.segmentation.save_weights`) may have an ``NAME.onnx``
beside it: the same network (batch norm folded) exported to ONNX by
``python -m branch_gym.segmenter_training export-onnx NAME.pt``, computing the sub-pixel logits
(:meth:`recon.segmentation.network.SegmenterNet.subpixel_logits`) of a (1, C, H, W) input whose
H and W are multiples of the network's ``size_multiple``. The export records the SHA-256 of the
``.pt`` it came from (metadata key :data:`WEIGHTS_DIGEST_KEY`); :func:`load_onnx_network` uses the
ONNX file only while that digest matches, so a retrained ``.pt`` is never run with stale
weights. Measured on one core (``make bench``: ``segment_ms`` against ``segment_torch_ms``),
ONNX Runtime runs this network in about half of PyTorch's time.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import numpy as np

from recon.segmentation.weights import SegmenterWeightsError

logger = logging.getLogger(__name__)

WEIGHTS_DIGEST_KEY = "weights_sha256"
"""ONNX metadata key: the SHA-256 (hex) of the ``.pt`` file the network was exported from."""
INPUT_NAME = "x"
"""The ONNX graph's input: (1, C, H, W) float32."""
OUTPUT_NAME = "subpixel_logits"
"""The ONNX graph's output: (1, out_channels * 4, H / 2, W / 2) float32."""


def onnx_path_for(weights_path: str | Path) -> Path:
    """Where the ONNX export of a weights file lives: beside it, suffix ``.onnx``."""
    return Path(weights_path).with_suffix(".onnx")


def weights_digest(weights_path: str | Path) -> str:
    """SHA-256 (hex) of a weights file's bytes."""
    return hashlib.sha256(Path(weights_path).read_bytes()).hexdigest()


class OnnxNetwork:
    """A segmenter network exported to ONNX, run by ONNX Runtime on the CPU.

    Args:
        path: The ``.onnx`` file.
        threads: Intra-op threads (ONNX Runtime's thread pool; spinning off, so that idle threads
            do not take cores from other processes).

    Raises:
        SegmenterWeightsError: The file is missing or not a loadable ONNX model of this form.
    """

    def __init__(self, path: str | Path, threads: int = 1) -> None:
        import onnxruntime  # imported only where an ONNX file is loaded

        self.path = Path(path)
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        if not self.path.is_file():
            raise SegmenterWeightsError(f"segmenter ONNX file {self.path} does not exist")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self._session = onnxruntime.InferenceSession(
                str(self.path), options, providers=["CPUExecutionProvider"]
            )
        except Exception as error:  # onnxruntime raises its own types for a damaged model
            raise SegmenterWeightsError(
                f"segmenter ONNX file {self.path} is not a loadable ONNX model: {error}"
            ) from error
        inputs = [node.name for node in self._session.get_inputs()]
        outputs = [node.name for node in self._session.get_outputs()]
        if inputs != [INPUT_NAME] or outputs != [OUTPUT_NAME]:
            raise SegmenterWeightsError(
                f"segmenter ONNX file {self.path} has inputs {inputs} and outputs {outputs}, "
                f"expected [{INPUT_NAME!r}] and [{OUTPUT_NAME!r}] (export it with "
                "python -m branch_gym.segmenter_training export-onnx)"
            )
        metadata = self._session.get_modelmeta().custom_metadata_map
        self.weights_digest: str | None = metadata.get(WEIGHTS_DIGEST_KEY)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Sub-pixel logits of one padded input.

        Args:
            x: (1, C, H, W) float32 network input, H and W multiples of the network's
                ``size_multiple``.

        Returns:
            (1, out_channels * 4, H / 2, W / 2) float32 sub-pixel logits.
        """
        x = np.ascontiguousarray(x, dtype=np.float32)
        return self._session.run([OUTPUT_NAME], {INPUT_NAME: x})[0]


def load_onnx_network(weights_path: str | Path, threads: int = 1) -> OnnxNetwork | None:
    """The ONNX export beside a weights file, if there is one made from these weights.

    Args:
        weights_path: The ``.pt`` weights file.
        threads: Intra-op threads of ONNX Runtime.

    Returns:
        The network, or None (logged) where no ``.onnx`` lies beside the weights or where it was
        exported from other weights (its recorded digest differs): the caller then runs the
        ``.pt`` with PyTorch.

    Raises:
        SegmenterWeightsError: An ``.onnx`` file is there but cannot be loaded.
    """
    path = onnx_path_for(weights_path)
    if not path.is_file():
        logger.info("no ONNX export %s: the segmenter runs on PyTorch", path)
        return None
    network = OnnxNetwork(path, threads)
    digest = weights_digest(weights_path)
    if network.weights_digest != digest:
        logger.warning(
            "segmenter ONNX file %s was exported from other weights than %s (digest %s, the "
            "weights' %s): running the weights on PyTorch; re-export with "
            "python -m branch_gym.segmenter_training export-onnx %s",
            path, weights_path, network.weights_digest, digest, weights_path,
        )  # fmt: skip
        return None
    return network
