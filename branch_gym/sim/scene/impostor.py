"""Depth-correct impostors for the rows behind the scanned one: trees as sprites on planes.

At 3 m and more a tree's own depth spread (< 0.5 m) changes its image motion by under a fifth
and a pixel covers 8 mm or more, so renderers draw such trees as textured cards. Here each row
behind is one vertical plane (normal -y) carrying an RGBA texture onto which tree sprites are
blitted; ``sim/scene/orchard_background.py`` warps the plane into the pixels no body covers, with
the plane's exact depth (true parallax, correct ground-truth flow to within that spread).

The sprites come from a :class:`SpriteBank`: a few trees grown by the row's own generator
(``sim/scene/orchard_row.py``) and drawn orthographically once per process, from a fixed seed,
like a shipped asset library, and arranged into a few long strips of row (:class:`RowStrips`).
A scan's draws (the row's distance, which strip, where along it and which way round) come from
the scan's seed (:class:`~branch_gym.sim.scene.orchard_row.BackRow`): no texture work per scan.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import cv2
import numpy as np

from branch_gym.sim.scene.orchard_row import BackRow, OrchardRowConfig, grow_row_tree

__all__ = ["STRIP_COUNT", "ImpostorPlane", "RowStrips", "SpriteBank", "row_strips"]

SPRITE_COUNT = 12  # distinct tree sprites (our choice: repeats are not noticeable among 12)
STRIP_COUNT = 4  # distinct row strips (our choice; with offsets and mirroring, rows look new)
STRIP_LENGTH_M = 12.0  # a strip repeats along the row every 12 m (a 45 deg view spans ~8 m)
_SPRITE_SCALE_RANGE = (0.85, 1.15)  # tree size variation along a row (our choice)
_SPRITE_TWIGS_PER_BRANCH = (3, 8)  # seen whole from 3 m, a dormant tree is a mesh of shoots
_SPRITE_BANK_SEED = 31  # the asset library's fixed seed (not a scan's draw)
_SPRITE_TEXEL_M = 0.01  # 1 cm: a pixel covers 8 mm at 3.5 m from the camera (fx 416.8 px)
_SPRITE_HALF_WIDTH_M = 0.9  # branches reach at most this far from the trunk
_SPRITE_HEIGHT_M = 3.4  # tallest tree plus a margin
_LINE_ALPHA = 255
# Dormant apple wood seen in shade (linear RGB reflectance; reference.md trunk mean sRGB
# ~(72, 59, 43), one-year shoots redder, as in the real frames).
_WOOD_LINEAR = (0.09, 0.065, 0.045)
_SHOOT_LINEAR = (0.13, 0.06, 0.035)
_THICK_BRANCH_M = 0.004  # thicker than this: wood colour, else shoot colour


class SpriteBank:
    """RGBA tree sprites (linear colour premultiplied by alpha), bases at the bottom centre.

    Attributes:
        sprites: SPRITE_COUNT arrays (H, W, 4) float32; texel ``_SPRITE_TEXEL_M``.
    """

    def __init__(self, config: OrchardRowConfig, count: int = SPRITE_COUNT) -> None:
        rng = np.random.default_rng(_SPRITE_BANK_SEED)
        config = replace(config, twigs_per_branch_range=_SPRITE_TWIGS_PER_BRANCH)
        height_px = round(_SPRITE_HEIGHT_M / _SPRITE_TEXEL_M)
        width_px = 2 * round(_SPRITE_HALF_WIDTH_M / _SPRITE_TEXEL_M)
        self.sprites: list[np.ndarray] = []
        for _ in range(count):
            radius = rng.uniform(*config.trunk_radius_range_m)
            height = rng.uniform(*config.trunk_height_range_m)
            branches = grow_row_tree(
                config, rng, np.zeros(2), 0.0, radius, height, lateral_only=False,
                max_height_m=height,
            )  # fmt: skip
            colour = np.zeros((height_px, width_px, 3), np.float32)
            alpha = np.zeros((height_px, width_px), np.uint8)
            for branch in branches:
                x_px = branch.points[:, 0] / _SPRITE_TEXEL_M + width_px / 2
                y_px = height_px - 1 - branch.points[:, 2] / _SPRITE_TEXEL_M
                polyline = np.round(np.stack([x_px, y_px], 1) * 16).astype(np.int32)
                thickness = max(1, round(2 * float(branch.radii.mean()) / _SPRITE_TEXEL_M))
                cv2.polylines(alpha, [polyline], False, _LINE_ALPHA, thickness, cv2.LINE_AA, 4)
                tone = _WOOD_LINEAR if branch.radii[0] > _THICK_BRANCH_M else _SHOOT_LINEAR
                cv2.polylines(colour, [polyline], False, tone, thickness, cv2.LINE_8, 4)
            a = alpha.astype(np.float32) / _LINE_ALPHA
            self.sprites.append(np.dstack([colour * a[:, :, None], a]))


class RowStrips:
    """A few long strips of row texture, each a row of sprites, built once per process.

    A scan's row behind picks a strip, an offset along it and a direction (mirrored or not): the
    strip wraps along the row, so the plane needs no per-scan texture work.

    Attributes:
        strips: STRIP_COUNT arrays (H, W, 4) float32 premultiplied linear RGBA, row 0 at the top
            (``_SPRITE_HEIGHT_M`` above the ground), ``STRIP_LENGTH_M`` long.
    """

    def __init__(self, config: OrchardRowConfig) -> None:
        bank = SpriteBank(config)
        rng = np.random.default_rng(_SPRITE_BANK_SEED + 1)
        height_px = bank.sprites[0].shape[0]
        width_px = round(STRIP_LENGTH_M / _SPRITE_TEXEL_M)
        self.strips: list[np.ndarray] = []
        for _ in range(STRIP_COUNT):
            strip = np.zeros((height_px, width_px, 4), np.float32)
            x_m = rng.uniform(0.0, 1.0)
            while x_m < STRIP_LENGTH_M:
                sprite = bank.sprites[int(rng.integers(0, len(bank.sprites)))]
                if rng.random() < 0.5:
                    sprite = sprite[:, ::-1]
                scale = rng.uniform(*_SPRITE_SCALE_RANGE)
                size = (round(sprite.shape[1] * scale), round(sprite.shape[0] * scale))
                sprite = cv2.resize(sprite, size, interpolation=cv2.INTER_AREA)[-height_px:]
                left = round(x_m / _SPRITE_TEXEL_M) - sprite.shape[1] // 2
                columns = np.arange(left, left + sprite.shape[1]) % width_px  # wraps
                target = strip[height_px - sprite.shape[0] :, columns]
                target = target * (1.0 - sprite[:, :, 3:4]) + sprite
                strip[height_px - sprite.shape[0] :, columns] = target
                x_m += rng.uniform(*config.neighbour_spacing_range_m)
            self.strips.append(strip)


@functools.lru_cache(maxsize=4)
def row_strips(config: OrchardRowConfig) -> RowStrips:
    """The process's row strips for a row distribution (built once: ~0.3 s)."""
    return RowStrips(config)


class ImpostorPlane:
    """One row behind, as a textured plane facing the camera (normal -y).

    Attributes:
        texture: (H, W, 4) float32 premultiplied linear RGBA; row 0 at the top; it wraps
            along the row.
        texel_m: Texel size in metres.
        y_m: The plane's y.
        corner: (3,) world point of texel (0, 0).
        axis_u: (3,) unit along texture columns (+x, or -x when mirrored).
        axis_v: (3,) unit along texture rows (-z).
    """

    def __init__(self, row: BackRow, strips: RowStrips) -> None:
        self.texture = strips.strips[row.strip]
        self.texel_m = _SPRITE_TEXEL_M
        self.y_m = row.y_m
        direction = -1.0 if row.mirrored else 1.0
        self.corner = np.array([row.offset_m, row.y_m, self.texture.shape[0] * self.texel_m])
        self.axis_u = np.array([direction, 0.0, 0.0])
        self.axis_v = np.array([0.0, 0.0, -1.0])
