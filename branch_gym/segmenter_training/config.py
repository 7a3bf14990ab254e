"""Configuration of segmenter data generation, augmentation and training (all hyperparameters)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from recon.segmentation.flow import DIS_PRESETS
from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNetConfig

# Tree seeds of training data are drawn from [TRAIN_SEED_LOW, TRAIN_SEED_HIGH): disjoint from
# the evaluation seeds (eval.py uses 0-59; evaluate.py uses EVAL_SEED_OFFSET + i, i < 10_000).
TRAIN_SEED_LOW = 1_000_000
TRAIN_SEED_HIGH = 2_000_000_000
VALIDATION_SEED_OFFSET = 500_000
EVAL_SEED_OFFSET = 0
# What TrainConfig.skeleton_weight's term is computed on: "all" the branch pixels (clDice, the
# term first tried), "side" the side branches' skeleton alone (its recall half only).
SKELETON_TARGETS = ("all", "side")


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
class FlowAugmentConfig:
    """How a training frame's flow is made (module docstring, steps 2-4).

    Attributes:
        exact_probability: Use the renderer's exact flow (corrupted below); else DIS on the
            augmented frames. Both, so that the network leans on no one method's artefacts
            (the issue; our split). DIS is computed over the pair's own baseline (>= 7.5 mm,
            the pairing the segmenter runs with), where it often loses the thin tree
            (recon.segmentation.flow.DenseFlowConfig's benchmark): the network learns what that
            flow is worth.
        dis_presets: DIS presets drawn for the computed flow (the segmenter's is ultrafast).
        dis_weights: Their probabilities.
        smooth_sigma_range_px: Gaussian smoothing of the exact flow (learned flows bleed
            across edges: FlowNet2's are smooth, ``../shared/data/real_dev/*_flow.png``).
        coarse_probability: Compute the exact flow at 1 / coarse_factor and upsample it
            bilinearly (FlowNet2 predicts at a quarter of the resolution).
        coarse_factor: That factor.
        noise_fraction_range: Smooth noise added to the exact flow, as a fraction of its
            largest magnitude.
        drift_probability: Add a global flow (a camera turn the pairing let through; the real
            pictures' tinted backgrounds).
        drift_fraction_range: Its magnitude as a fraction of the largest flow.
        mirror_probability: Mirror the flow vectors (v -> -v) before turning them.
        no_flow_probability: Leave the picture white (a frame without a partner).
        near_twig_probability: Draw a near twig across the frame, a thin branch of another
            tree close to the camera moving faster than the scanned tree: the picture's
            normalisation is then that twig's flow and the tree reads paler (the real
            pictures are normalised by their largest flow, often such a twig; issue 61). 0:
            none, as the shipped weights were trained.
        near_twig_flow_gain_range: The twig's flow over the frame's largest flow.
        near_twig_width_range_px: Its width (a twig in focus to a blurred near one).
    """

    exact_probability: float = 0.5
    dis_presets: tuple[str, ...] = ("ultrafast", "fast", "medium")
    dis_weights: tuple[float, ...] = (0.6, 0.3, 0.1)
    smooth_sigma_range_px: tuple[float, float] = (0.0, 3.0)
    coarse_probability: float = 0.5
    coarse_factor: int = 4
    noise_fraction_range: tuple[float, float] = (0.0, 0.08)
    drift_probability: float = 0.5
    drift_fraction_range: tuple[float, float] = (0.0, 0.4)
    mirror_probability: float = 0.5
    no_flow_probability: float = 0.1
    near_twig_probability: float = 0.0
    near_twig_flow_gain_range: tuple[float, float] = (1.2, 3.0)
    near_twig_width_range_px: tuple[float, float] = (1.0, 4.0)

    def __post_init__(self) -> None:
        for name in (
            "near_twig_probability",
            "exact_probability",
            "coarse_probability",
            "drift_probability",
            "mirror_probability",
            "no_flow_probability",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"FlowAugmentConfig.{name} must be in [0, 1], got {value!r}")
        if not self.dis_presets or set(self.dis_presets) - set(DIS_PRESETS):
            raise ValueError(
                f"FlowAugmentConfig.dis_presets must name presets of {tuple(DIS_PRESETS)}, "
                f"got {self.dis_presets!r}"
            )
        if len(self.dis_weights) != len(self.dis_presets) or min(self.dis_weights) < 0:
            raise ValueError(
                "FlowAugmentConfig.dis_weights must hold one non-negative weight per preset, "
                f"got {self.dis_weights!r}"
            )
        if self.coarse_factor < 1:
            raise ValueError(
                f"FlowAugmentConfig.coarse_factor must be >= 1, got {self.coarse_factor!r}"
            )
        for name, floor in (("near_twig_flow_gain_range", 1.0), ("near_twig_width_range_px", 1.0)):
            low, high = getattr(self, name)
            if not floor <= low <= high:
                raise ValueError(
                    f"FlowAugmentConfig.{name} must be a (low, high) range with low >= {floor}, "
                    f"got {getattr(self, name)!r}"
                )


# A nearer negative's flow over the scanned tree's (our choice; OrchardAugmentConfig.
# nearer_negative_flow_ratio): at the scan's 0.2 m, 1.15 is ~2.6 cm in front of the bark, past
# the tree's own depth spread (trunks 1-4 cm thick).
NEARER_NEGATIVE_FLOW_RATIO = 1.15


@dataclass(frozen=True)
class OrchardAugmentConfig:
    """Everything random about a training frame of the flow-picture segmenter.

    Attributes:
        camera: Camera effects (shared with the RGB segmenter's randomisation).
        flow: How the flow is made.
        hue_shift_range_deg: Global hue shift of both frames (bark and sky colours).
        saturation_range: Global saturation gain.
        flip_probability: Horizontal flip (the flow's u flips with it).
        distractor_probability: Paste a copy of the scanned tree behind it that moves like the
            background (a negative only parallax tells apart: the paper's cue; our addition).
        overcast_probability: Give both frames another sky, an overcast one of any brightness
            (a vertical gradient with soft clouds), and light everything else from behind it,
            darker by ``backlight_gain_range``: the real close-ups look up at silhouettes
            against grey skies (``shared/data/real_dev``; reference.md, "Real close-up
            frames"), while the orchard world lights its bark from the front (our addition).
        overcast_brightness_range: The new sky's mean level (0-255).
        backlight_gain_range: Gain of every pixel that is not sky.
        details_as_background: The target leaves out the scanned tree's spurs, stubs and buds
            (``TreeGT.details``; a UFO tree's other uprights stay in). Real hand masks draw the
            trunk, uprights and side branches but not these (``shared/data/real_dev``), and the
            2D stage takes a spur in the mask for a short side branch. False: they are the
            scanned tree, as before (the shipped weights until 2026-12-04 were trained so).
            Needs shards that store ``n_secondaries``.
        nearer_negative_flow_ratio: Mark the pixels of everything else whose exact flow
            exceeds the scanned tree's median flow in the frame by this factor (under the pair's
            translation: nearer the camera, e.g. 1.15 at 0.2 m is ~2.6 cm in front) as nearer
            negatives (target :data:`~branch_gym.segmenter_training.generate.
            TARGET_NEARER_NEGATIVE`), which ``TrainConfig.nearer_negative_weight`` weighs. The
            neighbours' branches crossing in front of the tree are most of the false positives
            on orchard renders (docs/results/history.md, "The orchard segmenter"), and
            their larger parallax tells them apart. None: not marked.
    """

    camera: AugmentConfig = field(default_factory=AugmentConfig)
    flow: FlowAugmentConfig = field(default_factory=FlowAugmentConfig)
    hue_shift_range_deg: tuple[float, float] = (-15.0, 15.0)
    saturation_range: tuple[float, float] = (0.5, 1.3)
    flip_probability: float = 0.5
    distractor_probability: float = 0.3
    overcast_probability: float = 0.0
    overcast_brightness_range: tuple[float, float] = (50.0, 230.0)
    backlight_gain_range: tuple[float, float] = (0.2, 0.8)
    details_as_background: bool = False
    nearer_negative_flow_ratio: float | None = None

    def __post_init__(self) -> None:
        ratio = self.nearer_negative_flow_ratio
        if ratio is not None and not (math.isfinite(ratio) and ratio >= 1.0):
            raise ValueError(
                "OrchardAugmentConfig.nearer_negative_flow_ratio must be None or a finite "
                f"factor >= 1, got {ratio!r}"
            )
        for name in ("flip_probability", "distractor_probability", "overcast_probability"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"OrchardAugmentConfig.{name} must be in [0, 1], got {value!r}")
        for name, high in (("overcast_brightness_range", 255.0), ("backlight_gain_range", None)):
            low_value, high_value = getattr(self, name)
            if not 0.0 <= low_value <= high_value or (high is not None and high_value > high):
                bound = f" within [0, {high:g}]" if high is not None else " with low >= 0"
                raise ValueError(
                    f"OrchardAugmentConfig.{name} must be a (low, high) range{bound}, "
                    f"got {getattr(self, name)!r}"
                )

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        return asdict(self)


@dataclass(frozen=True)
class TrainConfig:
    """The training loop.

    Attributes:
        net: Architecture.
        flow: Flow normalisation.
        augment: Domain randomisation (RGB / flow-vector networks on clean-world pairs).
        orchard: Randomisation of flow-picture networks (``net.flow_picture``) on orchard
            pairs (:mod:`branch_gym.segmenter_training.orchard_augment`).
        steps: Optimiser steps.
        batch_size: Frames per step.
        crop_hw: Training crop (height, width) in pixels, multiples of the network's
            ``size_multiple``; cropped before augmentation (both cost in proportion to pixels).
        learning_rate: Peak AdamW learning rate (one-cycle schedule).
        encoder_learning_rate_scale: The encoder's learning rate as a share of
            ``learning_rate`` (1: the same; below 1 a pretrained encoder keeps more of its
            ImageNet features, the usual lever for transfer to real images).
        weight_decay: AdamW weight decay.
        warmup_fraction: Fraction of the steps spent warming up.
        dice_weight: Weight of the soft-Dice term next to the binary cross-entropy.
        side_branch_weight: Weight of side-branch pixels in the cross-entropy (1: as every
            pixel). Side branches are a few pixels wide and a third of their pixels were missed
            at 1 (docs/results/history.md, "The orchard segmenter"), while the rotations that find
            them need them whole.
        nearer_negative_weight: Weight of the nearer negatives in the cross-entropy (pixels
            of other objects in front of the tree: ``OrchardAugmentConfig.
            nearer_negative_flow_ratio`` marks them; 1: as every pixel).
        skeleton_weight: Weight of the clDice term (Shit et al. 2021, "clDice - a novel
            topology-preserving loss function for tubular structure segmentation"; 0: none,
            the shipped weights' loss). It weighs a thin side branch by its length, not its
            pixels: real frames' long thin side branches were left out (issue 61).
        skeleton_iterations: Erosions of its soft skeleton (clDice's k; half the widest
            trunk's width in a 160x224 crop, our choice).
        skeleton_target: What the term is computed on (one of :data:`SKELETON_TARGETS`):
            ``"all"`` clDice on every branch pixel (the term first tried: it kept thin side
            branches but thinned the trunk, its skeleton precision rewarding a thin mask,
            docs/orchard_segmenter.md); ``"side"`` the share of the side branches' target
            skeleton the prediction covers (clDice's recall half on side-branch pixels alone,
            as the "Skeleton Recall" loss of Kirchhoff et al. 2024): the trunk's pixels,
            predicted or not, never enter it.
        checkpoint_every: Steps between checkpoints.
        validate_every: Steps between validation IoU measurements.
        threshold: Branch probability threshold of the shipped segmenter.
        threads: torch intra-op threads.
    """

    net: SegmenterNetConfig = field(default_factory=SegmenterNetConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    orchard: OrchardAugmentConfig = field(default_factory=OrchardAugmentConfig)
    steps: int = 3000
    batch_size: int = 8
    crop_hw: tuple[int, int] = (160, 224)
    learning_rate: float = 4e-3
    encoder_learning_rate_scale: float = 1.0
    weight_decay: float = 1e-4
    warmup_fraction: float = 0.05
    dice_weight: float = 1.0
    side_branch_weight: float = 1.0
    nearer_negative_weight: float = 1.0
    skeleton_weight: float = 0.0
    skeleton_iterations: int = 10
    skeleton_target: str = "all"
    checkpoint_every: int = 100
    validate_every: int = 500
    threshold: float = 0.5
    threads: int = 1

    def __post_init__(self) -> None:
        if not 0.0 <= self.encoder_learning_rate_scale <= 1.0:
            raise ValueError(
                "TrainConfig.encoder_learning_rate_scale must be in [0, 1], got "
                f"{self.encoder_learning_rate_scale!r}"
            )
        for name in ("side_branch_weight", "nearer_negative_weight"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"TrainConfig.{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.skeleton_weight) and self.skeleton_weight >= 0.0):
            raise ValueError(
                f"TrainConfig.skeleton_weight must be finite and >= 0, got {self.skeleton_weight!r}"
            )
        if self.skeleton_iterations < 1:
            raise ValueError(
                f"TrainConfig.skeleton_iterations must be >= 1, got {self.skeleton_iterations!r}"
            )
        if self.skeleton_target not in SKELETON_TARGETS:
            raise ValueError(
                f"TrainConfig.skeleton_target must be one of {SKELETON_TARGETS}, got "
                f"{self.skeleton_target!r}"
            )

    def to_dict(self) -> dict:
        """Plain JSON-able values."""
        data = asdict(self)
        data["net"] = self.net.to_dict()
        return data
