"""Configuration of segmenter data generation, augmentation and training (all hyperparameters)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNetConfig

# Tree seeds of training data are drawn from [TRAIN_SEED_LOW, TRAIN_SEED_HIGH): disjoint from
# the evaluation seeds (eval.py uses 0-59; evaluate.py uses EVAL_SEED_OFFSET + i, i < 10_000).
TRAIN_SEED_LOW = 1_000_000
TRAIN_SEED_HIGH = 2_000_000_000
VALIDATION_SEED_OFFSET = 500_000
EVAL_SEED_OFFSET = 0


@dataclass(frozen=True)
class GenerateConfig:
    """Frames rendered along simulated scans.

    Each tree is one ``World.reset``; the camera first orbits the primary by a random angle
    and climbs to a random height, then ``pairs_per_tree`` (previous, current) frame pairs are
    rendered, the current one ``displacement_range_m`` of camera motion after the previous one.

    Attributes:
        trees: Number of trees.
        pairs_per_tree: Frame pairs per tree.
        trees_per_shard: Trees per data shard (``shard_XXXXX.npz``, written atomically).
        preset_weights: Probabilities of the tree presets (paper, cluttered, hard).
        thick_primary_probability: Chance of a thicker primary (radius up to ``thick_radius_m``,
            orchard branches are much thicker than the paper's).
        thick_radius_m: Upper primary radius of the thick variant.
        z_target_range_m: Camera-to-primary distance at home (paper: 0.20 m, orchard 0.4-0.6 m).
        start_height_range_m: Camera height at home.
        orbit_range_deg: Orbit around the primary before the pairs (view direction variety).
        roll_range_deg: Camera roll before the pairs.
        climb_range_m: Climb between pairs.
        displacement_range_m: Camera motion between the frames of a pair.
        lateral_speed_fraction: Lateral (x) speed as a fraction of the climb speed, at most.
        speed_mps: Camera speed used for the motions.
    """

    trees: int = 320
    pairs_per_tree: int = 8
    trees_per_shard: int = 16
    preset_weights: tuple[float, float, float] = (0.3, 0.4, 0.3)
    thick_primary_probability: float = 0.3
    thick_radius_m: float = 0.015
    z_target_range_m: tuple[float, float] = (0.13, 0.5)
    start_height_range_m: tuple[float, float] = (0.2, 0.55)
    orbit_range_deg: tuple[float, float] = (-50.0, 50.0)
    roll_range_deg: tuple[float, float] = (-15.0, 15.0)
    climb_range_m: tuple[float, float] = (0.0, 0.06)
    displacement_range_m: tuple[float, float] = (0.002, 0.015)
    lateral_speed_fraction: float = 0.3
    speed_mps: float = 0.05

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        return asdict(self)


@dataclass(frozen=True)
class AugmentConfig:
    """Image-space domain randomisation (probabilities and ranges).

    Attributes:
        flip_probability: Horizontal flip of the pair.
        bark_probability: Recolour the bark (HSV shift, blended noise texture).
        hue_shift_range_deg: Bark hue shift (OpenCV hue is 0-180 for 0-360 deg).
        saturation_range: Bark saturation gain.
        value_range: Bark brightness gain.
        bark_noise_alpha_range: Blend weight of a noise texture on the bark.
        background_probability: Replace background pixels (label 0) by a generated background.
        clutter_probability: Draw extra clutter (trunks, wires, posts) behind the tree.
        max_tubes: Most drawn background trunks / branches.
        max_wires: Most drawn trellis wires.
        max_posts: Most drawn posts.
        exposure_range: Global gain.
        gamma_range: Gamma exponent.
        contrast_range: Contrast around the mean.
        white_balance_range: Per-channel gain.
        blur_probability: Defocus (Gaussian) blur.
        blur_sigma_range_px: Its sigma.
        motion_blur_probability: Linear motion blur.
        motion_blur_length_range_px: Its kernel length.
        noise_probability: Gaussian sensor noise.
        noise_sigma_range: Its sigma (0-255 units).
        jpeg_probability: JPEG compression.
        jpeg_quality_range: Its quality.
        flow_drop_probability: Train without the flow planes (the first frame has no previous).
    """

    flip_probability: float = 0.5
    bark_probability: float = 0.8
    hue_shift_range_deg: tuple[float, float] = (-30.0, 30.0)
    saturation_range: tuple[float, float] = (0.4, 1.5)
    value_range: tuple[float, float] = (0.5, 1.5)
    bark_noise_alpha_range: tuple[float, float] = (0.0, 0.5)
    background_probability: float = 0.75
    clutter_probability: float = 0.6
    max_tubes: int = 4
    max_wires: int = 3
    max_posts: int = 1
    exposure_range: tuple[float, float] = (0.55, 1.5)
    gamma_range: tuple[float, float] = (0.65, 1.5)
    contrast_range: tuple[float, float] = (0.6, 1.3)
    white_balance_range: tuple[float, float] = (0.85, 1.15)
    blur_probability: float = 0.25
    blur_sigma_range_px: tuple[float, float] = (0.4, 1.4)
    motion_blur_probability: float = 0.15
    motion_blur_length_range_px: tuple[int, int] = (3, 7)
    noise_probability: float = 0.6
    noise_sigma_range: tuple[float, float] = (1.0, 8.0)
    jpeg_probability: float = 0.5
    jpeg_quality_range: tuple[int, int] = (35, 95)
    flow_drop_probability: float = 0.3

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        return asdict(self)


@dataclass(frozen=True)
class TrainConfig:
    """The training loop.

    Attributes:
        net: Architecture.
        flow: Flow normalisation.
        augment: Domain randomisation.
        steps: Optimiser steps.
        batch_size: Frames per step.
        crop_hw: Training crop (height, width) in pixels, multiples of the network's
            ``size_multiple``; cropped before augmentation (both cost in proportion to pixels).
        learning_rate: Peak AdamW learning rate (one-cycle schedule).
        weight_decay: AdamW weight decay.
        warmup_fraction: Fraction of the steps spent warming up.
        dice_weight: Weight of the soft-Dice term next to the binary cross-entropy.
        checkpoint_every: Steps between checkpoints.
        validate_every: Steps between validation IoU measurements.
        threshold: Branch probability threshold of the shipped segmenter.
        threads: torch intra-op threads.
    """

    net: SegmenterNetConfig = field(default_factory=SegmenterNetConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    steps: int = 3000
    batch_size: int = 8
    crop_hw: tuple[int, int] = (160, 224)
    learning_rate: float = 4e-3
    weight_decay: float = 1e-4
    warmup_fraction: float = 0.05
    dice_weight: float = 1.0
    checkpoint_every: int = 100
    validate_every: int = 500
    threshold: float = 0.5
    threads: int = 1

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        data = asdict(self)
        data["net"] = self.net.to_dict()
        return data
