"""Training batches of the flow-picture segmenter: orchard pairs -> (RGB, flow picture) -> mask.

A pair of the orchard world (:mod:`branch_gym.segmenter_training.orchard_pairs`) becomes one
training frame:

1. both frames get, sometimes, an overcast sky with the rest lit from behind
   (:func:`overcast_backlight`), then another camera's look
   (:func:`~branch_gym.segmenter_training.augment.camera_effects`: exposure, white balance,
   blur, noise, JPEG) and a colour shift;
2. the flow of the current frame is either the renderer's exact flow, corrupted the way
   learned flow networks err (smoothed across edges, predicted at a quarter resolution and
   upsampled, smooth noise, a global drift of the background), or OpenCV's DIS flow computed
   from the two augmented frames (the segmenter's own flow at run time);
3. the flow vectors are turned by a random angle (and mirrored half the time), so that the
   picture's hue, which codes the motion's direction, carries no cue: what is left is the
   parallax, the near tree saturated against a pale background (and recorded pictures of any
   direction convention read alike);
4. the flow is coded as the paper's colour-wheel picture normalised by the frame's largest flow
   (:func:`recon.segmentation.flow.flow_to_picture_fast`), or left white (no flow) in a few;
5. a flip and a crop.

Batch ``k`` is drawn from ``np.random.default_rng([seed, k])`` alone, so a resumed run sees
the batches an uninterrupted one would.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from branch_gym.segmenter_training.augment import camera_effects, smooth_noise
from branch_gym.segmenter_training.config import FlowAugmentConfig, OrchardAugmentConfig
from branch_gym.segmenter_training.generate import (
    TARGET_NEARER_NEGATIVE,
    branch_target,
    labels_to_classes,
)
from branch_gym.sim.scene.labels import SKY_LABEL, details_label, is_occluding_clutter
from recon.segmentation.flow import DenseFlowConfig, compute_flow
from recon.segmentation.flow import flow_to_picture_fast as flow_to_picture
from recon.segmentation.inputs import make_picture_input

_SKY_WINDOW_PX = 41  # window of the nearby sky's colour (our choice: ~the widest trunk)
_SKY_COLOUR_TOLERANCE = 25.0  # uint8 levels from it that still read as sky (our choice)
_SKY_MIN_NEARBY_SHARE = 0.05  # the colour rule needs that much sky in the window (our choice)
# The overcast sky (our choices, from the real dev frames' skies): brightness changing by up to
# +-25 % from top to bottom, clouds 20-80 px across of up to +-25 % of the level, a tint of up to
# 8 % per channel.
_OVERCAST_GRADIENT = 0.25
_OVERCAST_CLOUD_PX = (20.0, 80.0)
_OVERCAST_CLOUD_CONTRAST = 0.5
_OVERCAST_TINT = 0.08


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _recolour(frames: np.ndarray, rng: np.random.Generator, config: OrchardAugmentConfig):
    """(2, H, W, 3) uint8 frames with one hue shift and saturation gain."""
    shift = _uniform(rng, config.hue_shift_range_deg) / 2.0  # OpenCV hue: 0-180
    gain = _uniform(rng, config.saturation_range)
    out = np.empty_like(frames)
    for k, frame in enumerate(frames):
        hsv = cv2.cvtColor(frame, cv2.COLOR_RGB2HSV).astype(np.float32)
        hsv[..., 0] = np.mod(hsv[..., 0] + shift, 180.0)
        hsv[..., 1] = np.clip(hsv[..., 1] * gain, 0, 255)
        out[k] = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)
    return out


def corrupt_exact_flow(
    flow: np.ndarray, rng: np.random.Generator, config: FlowAugmentConfig
) -> np.ndarray:
    """The exact flow with the errors of a learned flow network (FlowAugmentConfig).

    Args:
        flow: (H, W, 2) float flow in pixels.
        rng: Draws the corruption.
        config: Its ranges.

    Returns:
        (H, W, 2) float32 flow.
    """
    flow = flow.astype(np.float32)
    h, w = flow.shape[:2]
    if rng.random() < config.coarse_probability and config.coarse_factor > 1:
        small = cv2.resize(flow, (w // config.coarse_factor, h // config.coarse_factor),
                           interpolation=cv2.INTER_AREA)  # fmt: skip
        flow = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    sigma = _uniform(rng, config.smooth_sigma_range_px)
    if sigma > 0.2:
        flow = cv2.GaussianBlur(flow, (0, 0), sigma)
    largest = float(np.sqrt((flow**2).sum(axis=2).max())) or 1.0
    amplitude = _uniform(rng, config.noise_fraction_range) * largest
    if amplitude > 0:
        cell = _uniform(rng, (8.0, 60.0))
        noise = np.stack([smooth_noise(rng, (h, w), cell) for _ in range(2)], axis=2) - 0.5
        flow = flow + np.float32(2 * amplitude) * noise
    if rng.random() < config.drift_probability:
        angle = rng.uniform(0, 2 * math.pi)
        size = _uniform(rng, config.drift_fraction_range) * largest
        flow = flow + np.float32([size * math.cos(angle), size * math.sin(angle)])
    return flow


def add_far_copy(
    rgb_pair: np.ndarray, exact_flow: np.ndarray, target: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Paste a copy of the scanned tree behind it, moving like the background: a negative.

    The copy looks exactly like the tree (colour alone cannot tell them apart) but moves with
    the row behind (the median flow of the frame's other pixels, in both frames at one place):
    only the parallax says it is not the scanned tree. It is pasted only where the tree is not
    (it stands behind it), at a random sideways offset.

    Args:
        rgb_pair: (2, H, W, 3) uint8 earlier and current frame.
        exact_flow: (H, W, 2) current-to-earlier flow (pixels).
        target: (H, W) bool scanned tree in the current frame.
        rng: Draws the offset.

    Returns:
        (the pair with the copy, the flow with the copy's background motion).
    """
    w = target.shape[1]
    if target.sum() < 50 or target.all():
        return rgb_pair, exact_flow
    shift = int(rng.integers(w // 6, w // 2)) * (1 if rng.random() < 0.5 else -1)
    copy = np.roll(target, shift, axis=1)
    copy[:, : max(shift, 0)] = False
    copy[:, w + min(shift, 0) :] = False
    copy &= ~target
    if not copy.any():
        return rgb_pair, exact_flow
    background = np.median(exact_flow[~target].reshape(-1, 2), axis=0)
    tree_pixels = np.roll(rgb_pair[1], shift, axis=1)
    pair = rgb_pair.copy()
    for frame in pair:  # the same place in both frames: (near) still, like the far row
        frame[copy] = tree_pixels[copy]
    flow = np.array(exact_flow, np.float32)
    flow[copy] = background
    return pair, flow


def earlier_mask(mask: np.ndarray, exact_flow: np.ndarray) -> np.ndarray:
    """Where a current frame's (H, W) bool mask lies in the earlier frame of its pair.

    Each pixel is carried along its current-to-earlier flow (rounded) and the holes of the
    splat closed by one pixel; pixels the current frame does not see stay False.
    """
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    u = np.rint(xs + exact_flow[ys, xs, 0]).astype(np.int64)
    v = np.rint(ys + exact_flow[ys, xs, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.zeros((h, w), np.uint8)
    out[v[inside], u[inside]] = 1
    return cv2.morphologyEx(out, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(bool)


def _earlier_sky(rgb_pair: np.ndarray, exact_flow: np.ndarray, sky_now: np.ndarray) -> np.ndarray:
    """(H, W) bool sky of the earlier frame of a pair, from the current frame's sky.

    Where the current frame's other pixels flow to is not sky (the near tree hides the sky);
    of the rest, where the current sky flows to is sky, and so are the pixels the current
    frame does not show (behind the moved tree) whose colour is the nearby sky's.
    """
    not_sky = earlier_mask(~sky_now, exact_flow)
    carried_sky = earlier_mask(sky_now, exact_flow) & ~not_sky
    unseen = ~carried_sky & ~not_sky
    if not unseen.any() or not sky_now.any():
        return carried_sky
    # The nearby sky's colour (normalised box filter of the current sky) at every pixel.
    window = (_SKY_WINDOW_PX, _SKY_WINDOW_PX)
    weight = cv2.boxFilter(sky_now.astype(np.float32), -1, window)
    total = cv2.boxFilter(rgb_pair[1].astype(np.float32) * sky_now[..., None], -1, window)
    colour = total / np.maximum(weight, 1e-6)[..., None]
    close = np.abs(rgb_pair[0].astype(np.float32) - colour).max(axis=-1) < _SKY_COLOUR_TOLERANCE
    return carried_sky | (unseen & close & (weight > _SKY_MIN_NEARBY_SHARE))


def overcast_backlight(
    rgb_pair: np.ndarray,
    exact_flow: np.ndarray,
    labels: np.ndarray,
    rng: np.random.Generator,
    config: OrchardAugmentConfig,
) -> np.ndarray:
    """Both frames under an overcast sky, everything else lit from behind (a silhouette).

    The sky (``SKY_LABEL`` of the current frame; in the earlier frame, :func:`_earlier_sky`)
    becomes one overcast sky, still in both frames like the rendered one: a vertical gradient
    around a drawn brightness with soft clouds and a faint tint. Every other pixel is darkened
    by one drawn gain.

    Args:
        rgb_pair: (2, H, W, 3) uint8 earlier and current frame.
        exact_flow: (H, W, 2) current-to-earlier flow (pixels).
        labels: (H, W) instance labels of the current frame.
        rng: Draws the sky and the gain.
        config: The ranges.

    Returns:
        (2, H, W, 3) uint8 frames.
    """
    h, w = labels.shape
    sky_now = labels == SKY_LABEL
    skies = (_earlier_sky(rgb_pair, exact_flow, sky_now), sky_now)
    level = _uniform(rng, config.overcast_brightness_range)
    rows = np.linspace(-1.0, 1.0, h, dtype=np.float32)[:, None]
    gradient = level * (1.0 + rng.uniform(-_OVERCAST_GRADIENT, _OVERCAST_GRADIENT) * rows)
    clouds = smooth_noise(rng, (h, w), _uniform(rng, _OVERCAST_CLOUD_PX)) - 0.5
    grey = gradient + clouds * rng.uniform(0.0, _OVERCAST_CLOUD_CONTRAST) * level
    tint = 1.0 + rng.uniform(-_OVERCAST_TINT, _OVERCAST_TINT, size=3).astype(np.float32)
    sky = np.clip(grey[..., None] * tint, 0, 255).astype(np.uint8)
    gain = _uniform(rng, config.backlight_gain_range)
    out = np.empty_like(rgb_pair)
    for k, (frame, is_sky) in enumerate(zip(rgb_pair, skies, strict=True)):
        lit = np.clip(frame.astype(np.float32) * gain, 0, 255).astype(np.uint8)
        out[k] = np.where(is_sky[..., None], sky, lit)
    return out


def mark_nearer_negatives(
    target: np.ndarray, labels: np.ndarray, exact_flow: np.ndarray, flow_ratio: float
) -> np.ndarray:
    """The target with the other objects in front of the scanned tree marked apart.

    Args:
        target: (H, W) uint8 :func:`~branch_gym.segmenter_training.generate.branch_target`.
        labels: (H, W) instance labels of the frame.
        exact_flow: (H, W, 2) the renderer's flow of the frame (pixels).
        flow_ratio: A pixel of another object (posts, wires, the row's trees: labels that
            :func:`~branch_gym.sim.scene.labels.is_occluding_clutter` names) is nearer when its
            flow exceeds the tree's median flow by this factor.

    Returns:
        (H, W) uint8 target, :data:`~branch_gym.segmenter_training.generate.
        TARGET_NEARER_NEGATIVE` where nearer; unchanged when the frame shows no tree or the
        tree does not move.
    """
    tree = target > 0
    if not tree.any():
        return target
    speed = np.hypot(exact_flow[..., 0], exact_flow[..., 1])
    tree_speed = float(np.median(speed[tree]))
    if tree_speed <= 0.0:
        return target
    nearer = is_occluding_clutter(labels) & (speed > flow_ratio * tree_speed)
    marked = target.copy()
    marked[nearer] = TARGET_NEARER_NEGATIVE
    return marked


def add_near_twig(
    current: np.ndarray,
    flow: np.ndarray,
    classes: np.ndarray,
    rng: np.random.Generator,
    config: FlowAugmentConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A thin twig close to the camera across the frame: it sets the flow picture's scale.

    A gently curved line from one frame border to another, as dark as the scanned tree's bark,
    moving like the tree (its median flow direction) but ``near_twig_flow_gain_range`` times
    faster than the frame's largest flow; it hides what lies behind it (target 0 there).

    Args:
        current: (H, W, 3) uint8 current frame.
        flow: (H, W, 2) float32 flow of that frame (pixels).
        classes: (H, W) uint8 target (0 background).
        rng: Draws the twig.
        config: Its ranges.

    Returns:
        (frame, flow, target) with the twig; unchanged when the frame shows no tree.
    """
    tree = (classes > 0) & (classes != TARGET_NEARER_NEGATIVE)
    if not tree.any():
        return current, flow, classes
    h, w = classes.shape
    speed = np.hypot(flow[..., 0], flow[..., 1])
    largest = float(speed.max())
    if largest == 0.0:
        return current, flow, classes
    direction = np.median(flow[tree], axis=0)
    direction = direction / max(float(np.hypot(*direction)), 1e-6)

    # Two points on the border (one of the four sides each), a bend in between.
    def border_point() -> np.ndarray:
        side, t = int(rng.integers(4)), float(rng.random())
        return np.array(((t * w, 0.0), (t * w, h - 1.0), (0.0, t * h), (w - 1.0, t * h))[side])

    start, end = border_point(), border_point()
    middle = (start + end) / 2 + rng.normal(0.0, 0.15 * min(h, w), 2)
    t = np.linspace(0.0, 1.0, 64)[:, None]
    points = (1 - t) ** 2 * start + 2 * (1 - t) * t * middle + t**2 * end
    width = _uniform(rng, config.near_twig_width_range_px)
    twig = np.zeros((h, w), np.uint8)
    cv2.polylines(twig, [np.rint(points).astype(np.int32)], False, 1, max(1, round(width)))
    twig = twig.astype(bool)
    bark = np.median(current[tree], axis=0)
    frame = current.copy()
    frame[twig] = bark.astype(np.uint8)
    frame = np.where(twig[..., None], cv2.GaussianBlur(frame, (0, 0), 0.7), frame)
    gain = _uniform(rng, config.near_twig_flow_gain_range)
    flow = flow.copy()
    flow[twig] = (gain * largest * direction).astype(np.float32)
    classes = classes.copy()
    classes[twig] = 0
    return frame, flow, classes


def _turn(flow: np.ndarray, rng: np.random.Generator, config: FlowAugmentConfig) -> np.ndarray:
    """Flow vectors turned by a random angle, mirrored first with ``mirror_probability``."""
    u, v = flow[..., 0], flow[..., 1]
    if rng.random() < config.mirror_probability:
        v = -v
    angle = rng.uniform(0, 2 * math.pi)
    c, s = np.float32(math.cos(angle)), np.float32(math.sin(angle))
    return np.stack([c * u - s * v, s * u + c * v], axis=2)


def training_frame(
    rgb_pair: np.ndarray,
    exact_flow: np.ndarray,
    labels: np.ndarray,
    rng: np.random.Generator,
    config: OrchardAugmentConfig,
    crop_hw: tuple[int, int],
    details_label: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One randomised training frame of an orchard pair (module docstring).

    Args:
        rgb_pair: (2, H, W, 3) uint8 earlier and current frame.
        exact_flow: (H, W, 2) float current-to-earlier flow in pixels.
        labels: (H, W) current frame's instance labels.
        rng: Draws everything.
        config: The randomisation.
        crop_hw: Crop (height, width).
        details_label: The label of the tree's spurs, stubs and buds
            (:func:`branch_gym.sim.scene.labels.details_label`); needed when
            ``config.details_as_background``.

    Returns:
        ((6, h, w) float32 network input, (h, w) uint8 target: 0 not the scanned tree,
        1 its primary, 2 a side branch (:func:`~branch_gym.segmenter_training.generate.
        branch_target`)).
    """
    classes = branch_target(labels_to_classes(labels))
    if config.details_as_background:
        if details_label is None:
            raise ValueError("details_as_background needs the pair's details_label")
        classes[labels == details_label] = 0
    target = classes > 0
    if config.nearer_negative_flow_ratio is not None:
        classes = mark_nearer_negatives(
            classes, labels, exact_flow, config.nearer_negative_flow_ratio
        )
    if rng.random() < config.distractor_probability:
        rgb_pair, exact_flow = add_far_copy(rgb_pair, exact_flow, target, rng)
    if rng.random() < config.overcast_probability:
        rgb_pair = overcast_backlight(rgb_pair, exact_flow, labels, rng, config)
    frames = camera_effects(rgb_pair, rng, config.camera)
    frames = _recolour(frames, rng, config)
    current = frames[1]
    flow_config = config.flow
    if rng.random() < flow_config.no_flow_probability:
        picture = None
    else:
        if rng.random() < flow_config.exact_probability:
            flow = corrupt_exact_flow(exact_flow, rng, flow_config)
        else:
            weights = np.asarray(flow_config.dis_weights, float)
            preset = flow_config.dis_presets[rng.choice(len(weights), p=weights / weights.sum())]
            flow = compute_flow(frames[0], frames[1], DenseFlowConfig(preset=str(preset)))
        # Drawn only when asked for, so that recipes without twigs keep their batches.
        if (
            flow_config.near_twig_probability > 0
            and rng.random() < flow_config.near_twig_probability
        ):
            current, flow, classes = add_near_twig(current, flow, classes, rng, flow_config)
        picture = flow_to_picture(_turn(flow, rng, flow_config))
    if rng.random() < config.flip_probability:  # a mirrored world: the picture mirrors too
        current, classes = current[:, ::-1], classes[:, ::-1]
        picture = None if picture is None else picture[:, ::-1]
    h, w = current.shape[:2]
    ch, cw = crop_hw
    top, left = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    window = (slice(top, top + ch), slice(left, left + cw))
    current = np.ascontiguousarray(current[window])
    picture = None if picture is None else np.ascontiguousarray(picture[window])
    return make_picture_input(current, picture), np.ascontiguousarray(classes[window])


class OrchardPairBatches(torch.utils.data.Dataset):
    """Batch ``k`` of a run on orchard pairs: ((B, 6, h, w) input, (B, 1, h, w) target).

    Args:
        data: Arrays of :func:`~branch_gym.segmenter_training.orchard_pairs.load_orchard_shards`.
        config: Randomisation.
        steps: Number of batches.
        batch_size: Frames per batch.
        crop_hw: Crop (height, width).
        seed: Run seed.
    """

    def __init__(
        self,
        data: dict[str, np.ndarray],
        config: OrchardAugmentConfig,
        steps: int,
        batch_size: int,
        crop_hw: tuple[int, int],
        seed: int,
    ) -> None:
        if config.details_as_background and "n_secondaries" not in data:
            raise ValueError(
                "details_as_background needs shards that store n_secondaries: generate them "
                "again with `python -m branch_gym.segmenter_training generate-orchard`"
            )
        self.data, self.config, self.steps = data, config, steps
        self.batch_size, self.crop_hw, self.seed = batch_size, crop_hw, seed

    def _details_label(self, index: int) -> int | None:
        if "n_secondaries" not in self.data:
            return None
        return details_label(int(self.data["n_secondaries"][index]))

    def __len__(self) -> int:
        return self.steps

    def __getitem__(self, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        cv2.setNumThreads(1)
        rng = np.random.default_rng([self.seed, step])
        indices = rng.integers(0, len(self.data["rgb"]), size=self.batch_size)
        inputs, targets = [], []
        for i in indices:
            x, y = training_frame(
                self.data["rgb"][i], self.data["flow"][i], self.data["labels"][i], rng,
                self.config, self.crop_hw, self._details_label(i),
            )  # fmt: skip
            inputs.append(x)
            targets.append(y[None].astype(np.float32))
        return torch.from_numpy(np.stack(inputs)), torch.from_numpy(np.stack(targets))
