"""Image-space domain randomisation of (previous, current) frame pairs.

The simulator's frames are clean: one bark texture, one foliage wall, flat lighting. Real
orchard photographs have other bark colours, sky, ground, trellis wires, posts, other trees
behind (background for the segmenter, as in the paper's orchard trials, section VI-C), changing
exposure, blur, noise and compression. Everything here is drawn from the ``rng`` it is given and
applied identically to both frames of a pair, except for motion: whatever is drawn moves between
the two frames like the scanned tree does (scaled down for the background, which is farther), so
that the optical flow computed afterwards stays meaningful.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from branch_gym.segmenter_training.config import AugmentConfig
from branch_gym.segmenter_training.generate import (
    CLASS_BACKGROUND,
    CLASS_CLUTTER,
    CLASS_PRIMARY,
    CLASS_SECONDARY,
)


def _u(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: float) -> np.ndarray:
    """(H, W) float32 smooth noise in [0, 1]: a random grid upsampled with cubic interpolation."""
    h, w = shape
    gh, gw = max(2, int(h / cell_px) + 2), max(2, int(w / cell_px) + 2)
    grid = rng.random((gh, gw)).astype(np.float32)
    big = cv2.resize(grid, (int(gw * cell_px), int(gh * cell_px)), interpolation=cv2.INTER_CUBIC)
    return np.clip(big[:h, :w], 0.0, 1.0)


def _tree_shift(classes: np.ndarray) -> np.ndarray:
    """(2,) pixel shift (dx, dy) of the scanned tree's centroid from the previous to current."""
    centroids = []
    for frame in classes:
        ys, xs = np.nonzero((frame == CLASS_PRIMARY) | (frame == CLASS_SECONDARY))
        if len(xs) == 0:
            return np.zeros(2)
        centroids.append(np.array([xs.mean(), ys.mean()]))
    return centroids[1] - centroids[0]


def _shifted(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``image`` translated by ``shift`` (dx, dy) pixels, borders reflected."""
    matrix = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    h, w = image.shape[:2]
    return cv2.warpAffine(image, matrix, (w, h), borderMode=cv2.BORDER_REFLECT)


def _random_colour(rng: np.random.Generator, kind: str) -> np.ndarray:
    """(3,) float RGB in 0-255 for a kind of surface."""
    hsv_ranges = {  # OpenCV HSV: hue 0-180
        "sky": ((95, 120), (10, 120), (150, 255)),
        "foliage": ((30, 85), (60, 230), (30, 200)),
        "ground": ((5, 35), (40, 180), (40, 170)),
        "bark": ((0, 30), (20, 160), (40, 200)),
        "grey": ((0, 180), (0, 40), (40, 220)),
        "dark": ((0, 180), (0, 80), (10, 80)),
    }[kind]
    hsv = np.uint8([[[_u(rng, r) for r in hsv_ranges]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _textured(rng: np.random.Generator, shape: tuple[int, int], kind: str) -> np.ndarray:
    """(H, W, 3) float32 surface: two colours of ``kind`` mixed by multi-scale noise."""
    a, b = _random_colour(rng, kind), _random_colour(rng, kind)
    t = 0.6 * smooth_noise(rng, shape, _u(rng, (8, 60))) + 0.4 * smooth_noise(
        rng, shape, _u(rng, (2, 8))
    )
    if rng.random() < 0.5:  # blobs (leaves, clouds): sharpen the mix
        t = np.clip((t - 0.5) * _u(rng, (2, 6)) + 0.5, 0, 1)
    return a * t[..., None] + b * (1 - t[..., None])


def make_background(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) float32 random scene behind the tree: sky/foliage/rows above ground.

    The horizon is at a random height (or outside the frame), above it sky, a foliage wall or
    an orchard row (blurred vertical trunks in front of foliage), below it ground.
    """
    h, w = shape
    upper_kind = rng.choice(["sky", "foliage", "rows", "noise"], p=[0.25, 0.35, 0.25, 0.15])
    if upper_kind == "sky":
        top, bottom = _random_colour(rng, "sky"), _random_colour(rng, "sky")
        ramp = np.linspace(0, 1, h, dtype=np.float32)[:, None, None]
        upper = np.broadcast_to(top * (1 - ramp) + bottom * ramp, (h, w, 3)).copy()
        if rng.random() < 0.5:  # clouds
            clouds = smooth_noise(rng, shape, _u(rng, (30, 90)))[..., None]
            upper = upper * (1 - 0.5 * clouds) + 240 * 0.5 * clouds
    elif upper_kind == "noise":  # photo-like clutter: many colours, blurred
        upper = _textured(rng, shape, str(rng.choice(["foliage", "ground", "grey"])))
        upper = 0.5 * upper + 0.5 * _textured(rng, shape, str(rng.choice(["sky", "bark"])))
    else:
        upper = _textured(rng, shape, "foliage")
    if upper_kind == "rows":  # distant orchard rows: vertical trunks, blurred
        for _ in range(int(rng.integers(3, 12))):
            x = _u(rng, (0, w))
            width = _u(rng, (2, 14))
            colour = _random_colour(rng, "bark") * _u(rng, (0.4, 0.9))
            cv2.line(upper, (int(x), 0), (int(x + _u(rng, (-30, 30))), h), colour.tolist(),
                     max(1, int(width)))  # fmt: skip
        upper = cv2.GaussianBlur(upper, (0, 0), _u(rng, (1.0, 3.0)))
    horizon = int(rng.uniform(-0.2, 1.3) * h)
    if horizon >= h:
        return upper
    ground = _textured(rng, shape, "ground")
    rows = np.arange(h)[:, None, None]
    blend = np.clip((rows - horizon) / _u(rng, (1, 10)), 0, 1).astype(np.float32)
    return upper * (1 - blend) + ground * blend


def draw_clutter(
    rng: np.random.Generator, shape: tuple[int, int], config: AugmentConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Extra clutter behind the tree: trunks/branches, trellis wires, posts.

    Returns:
        ((H, W, 3) float32 colours, (H, W) float32 coverage in [0, 1]).
    """
    h, w = shape
    colour = np.zeros((h, w, 3), np.float32)
    cover = np.zeros((h, w), np.float32)
    shade = _textured(rng, shape, "grey") / 255.0 * 0.5 + 0.75  # shared surface texture

    def stroke(points: np.ndarray, width: int, rgb: np.ndarray, blur: float) -> None:
        layer = np.zeros((h, w), np.float32)
        cv2.polylines(layer, [points.astype(np.int32)], False, 1.0, max(1, width), cv2.LINE_AA)
        if blur > 0:
            layer = cv2.GaussianBlur(layer, (0, 0), blur)
        colour[:] = colour * (1 - layer[..., None]) + (rgb * shade) * layer[..., None]
        cover[:] = np.maximum(cover, layer)

    for _ in range(int(rng.integers(0, config.max_tubes + 1))):  # background trunks / branches
        x0, x1 = _u(rng, (-0.1 * w, 1.1 * w)), _u(rng, (-0.1 * w, 1.1 * w))
        if rng.random() < 0.3:  # a side branch of a tree behind: more horizontal
            pts = np.array([[x0, _u(rng, (0, h))], [x1, _u(rng, (0, h))]])
        else:
            pts = np.array([[x0, h + 10], [0.5 * (x0 + x1) + _u(rng, (-20, 20)), h / 2],
                            [x1, -10]])  # fmt: skip
        rgb = _random_colour(rng, "bark") * _u(rng, (0.5, 1.1))
        stroke(pts, int(_u(rng, (2, 30))), rgb, _u(rng, (0, 2.5)))
    for _ in range(int(rng.integers(0, config.max_wires + 1))):  # trellis wires, ties
        y0 = _u(rng, (0, h))
        pts = np.array([[-10, y0], [w + 10, y0 + _u(rng, (-0.3, 0.3)) * w]])
        rgb = _random_colour(rng, str(rng.choice(["dark", "grey"])))
        stroke(pts, int(_u(rng, (1, 3))), rgb, _u(rng, (0, 0.8)))
    for _ in range(int(rng.integers(0, config.max_posts + 1))):  # posts: wide, straight, grey
        if rng.random() < 0.5:
            continue
        x0 = _u(rng, (0, w))
        pts = np.array([[x0, h + 10], [x0 + _u(rng, (-20, 20)), -10]])
        rgb = _random_colour(rng, str(rng.choice(["grey", "bark"])))
        stroke(pts, int(_u(rng, (15, 60))), rgb, _u(rng, (0, 1.5)))
    return colour, cover


def _recolour_bark(
    rng: np.random.Generator, image: np.ndarray, mask: np.ndarray, config: AugmentConfig,
    texture: np.ndarray, params: tuple[float, float, float, float],
) -> None:  # fmt: skip
    """In place: HSV shift and texture blend on the pixels of ``mask``."""
    if not mask.any():
        return
    hue, sat, val, alpha = params
    hsv = cv2.cvtColor(np.clip(image, 0, 255).astype(np.uint8), cv2.COLOR_RGB2HSV).astype(
        np.float32
    )
    hsv[..., 0] = (hsv[..., 0] + hue / 2.0) % 180.0
    hsv[..., 1] = np.clip(hsv[..., 1] * sat, 0, 255)
    hsv[..., 2] = np.clip(hsv[..., 2] * val, 0, 255)
    shifted = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB).astype(np.float32)
    shifted = shifted * (1 - alpha) + texture * alpha
    image[mask] = shifted[mask]


def augment_pair(
    rgb: np.ndarray, classes: np.ndarray, rng: np.random.Generator, config: AugmentConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Randomise one (previous, current) pair.

    Args:
        rgb: (2, H, W, 3) uint8 previous and current frame.
        classes: (2, H, W) uint8 class maps (``generate.CLASS_*``).
        rng: Source of every draw.
        config: Probabilities and ranges.

    Returns:
        ((2, H, W, 3) uint8 frames, (2, H, W) uint8 class maps), flipped like the frames.
    """
    frames = rgb.astype(np.float32)
    classes = classes.copy()
    if rng.random() < config.flip_probability:
        frames, classes = frames[:, :, ::-1].copy(), classes[:, :, ::-1].copy()
    shape = frames.shape[1:3]
    shift = _tree_shift(classes)
    tree = (classes == CLASS_PRIMARY) | (classes == CLASS_SECONDARY)
    clutter = classes == CLASS_CLUTTER

    if rng.random() < config.bark_probability:
        params = (_u(rng, config.hue_shift_range_deg), _u(rng, config.saturation_range),
                  _u(rng, config.value_range), _u(rng, config.bark_noise_alpha_range))  # fmt: skip
        texture = _textured(rng, shape, "bark")
        same_bark = rng.random() < 0.6  # trees behind are usually of the same species
        clutter_params = params if same_bark else (
            _u(rng, config.hue_shift_range_deg), _u(rng, config.saturation_range),
            _u(rng, config.value_range), _u(rng, config.bark_noise_alpha_range))  # fmt: skip
        for k in range(2):
            tex = texture if k == 1 else _shifted(texture, -shift)
            _recolour_bark(rng, frames[k], tree[k], config, tex, params)
            _recolour_bark(rng, frames[k], clutter[k], config, tex, clutter_params)

    behind_fraction = _u(rng, (0.0, 0.6))  # background moves less than the tree (farther)
    if rng.random() < config.background_probability:
        background = make_background(rng, shape)
        for k in range(2):
            bg = background if k == 1 else _shifted(background, -shift * behind_fraction)
            empty = classes[k] == CLASS_BACKGROUND
            frames[k][empty] = bg[empty]
    if rng.random() < config.clutter_probability:
        colour, cover = draw_clutter(rng, shape, config)
        clutter_fraction = _u(rng, (behind_fraction, 0.9))
        for k in range(2):
            c, a = (colour, cover) if k == 1 else (
                _shifted(colour, -shift * clutter_fraction),
                _shifted(cover, -shift * clutter_fraction))  # fmt: skip
            a = a * (classes[k] != CLASS_PRIMARY) * (classes[k] != CLASS_SECONDARY)
            frames[k] = frames[k] * (1 - a[..., None]) + c * a[..., None]

    return camera_effects(frames, rng, config), classes


def camera_effects(
    frames: np.ndarray, rng: np.random.Generator, config: AugmentConfig
) -> np.ndarray:
    """Another camera's look on the frames of one scan.

    Exposure, gamma, contrast, white balance, uneven light, blur, motion blur, noise and JPEG
    are drawn once and applied to every frame (with a little exposure flicker; the noise is
    drawn per frame).

    Args:
        frames: (K, H, W, 3) float32 or uint8 RGB frames in 0-255.
        rng: Draws every setting.
        config: Ranges and probabilities.

    Returns:
        (K, H, W, 3) uint8 frames.
    """
    frames = frames.astype(np.float32)
    shape = frames.shape[1:3]
    # Photometric: the same camera settings for both frames, with a little flicker.
    exposure, gamma = _u(rng, config.exposure_range), _u(rng, config.gamma_range)
    contrast = _u(rng, config.contrast_range)
    balance = rng.uniform(*config.white_balance_range, size=3).astype(np.float32)
    if rng.random() < 0.3:  # uneven light: a smooth gain field (sun patches, shade)
        gain = 0.6 + 0.8 * smooth_noise(rng, shape, _u(rng, (40, 120)))[..., None]
    else:
        gain = np.ones((*shape, 1), np.float32)
    for k in range(len(frames)):
        x = frames[k] * balance * gain * (exposure * (1 + 0.02 * rng.standard_normal()))
        x = 255.0 * np.power(np.clip(x / 255.0, 0, 1), gamma)
        frames[k] = (x - x.mean()) * contrast + x.mean()

    sigma = _u(rng, config.blur_sigma_range_px) if rng.random() < config.blur_probability else 0
    motion = None
    if rng.random() < config.motion_blur_probability:
        length = int(rng.integers(*config.motion_blur_length_range_px, endpoint=True))
        kernel = np.zeros((length, length), np.float32)
        angle = rng.uniform(0, math.pi)
        c = (length - 1) / 2
        dx, dy = math.cos(angle) * c, math.sin(angle) * c
        cv2.line(kernel, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1)
        motion = kernel / kernel.sum()
    noise = _u(rng, config.noise_sigma_range) if rng.random() < config.noise_probability else 0
    quality = (
        int(rng.integers(*config.jpeg_quality_range, endpoint=True))
        if rng.random() < config.jpeg_probability
        else None
    )
    out = np.empty(frames.shape, np.uint8)
    for k in range(len(frames)):
        x = frames[k]
        if sigma:
            x = cv2.GaussianBlur(x, (0, 0), sigma)
        if motion is not None:
            x = cv2.filter2D(x, -1, motion)
        if noise:
            x = x + rng.normal(0, noise, x.shape).astype(np.float32)
        x = np.clip(x, 0, 255).astype(np.uint8)
        if quality is not None:
            ok, buf = cv2.imencode(".jpg", x[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                raise RuntimeError("OpenCV failed to JPEG-encode an augmented frame")
            x = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
        out[k] = x
    return out
