"""Segmentation models on a small synthetic label image."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from branch_gym.sim.segmentation import (
    SEGMENTER_NAMES,
    GroundTruthSegmenter,
    NoisySegmenter,
    NoisySegmenterConfig,
    make_segmenter,
)

HEIGHT, WIDTH = 240, 320
PRIMARY, THICK_SECONDARY, THIN_SECONDARY = 1, 2, 3
TRUNK, WIRE = 100, 101
# Every failure mode off: a NoisySegmenter with this config must equal the ground truth.
QUIET = NoisySegmenterConfig(
    boundary_jitter_px=0.0,
    thin_drop_prob=0.0,
    blob_rate=0.0,
    clutter_leak_prob=0.0,
    chunk_rate=0.0,
)


def _scene() -> tuple[np.ndarray, np.ndarray]:
    """A 22 px primary, a 13 px and a 5 px secondary, a background trunk and a wire."""
    labels = np.zeros((HEIGHT, WIDTH), np.int32)
    cv2.line(labels, (290, 239), (300, 0), TRUNK, 30)
    cv2.line(labels, (0, 20), (319, 20), WIRE, 3)
    cv2.line(labels, (160, 239), (150, 0), PRIMARY, 22)
    cv2.line(labels, (158, 150), (250, 100), THICK_SECONDARY, 12)
    cv2.line(labels, (155, 90), (60, 50), THIN_SECONDARY, 3)
    rgb = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    rgb[labels > 0] = (120, 90, 60)
    return rgb, labels


def _gt(labels: np.ndarray) -> np.ndarray:
    return np.isin(labels, [PRIMARY, THICK_SECONDARY, THIN_SECONDARY])


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_ground_truth_segmenter_is_exact() -> None:
    rgb, labels = _scene()
    labels[5, 5] = 2 + 97  # the last secondary label
    labels[6, 6] = 100 + 500  # a far clutter label
    mask = GroundTruthSegmenter().segment(rgb, labels, np.random.default_rng(0))
    assert mask.dtype == bool and mask.shape == labels.shape
    assert mask[5, 5] and not mask[6, 6]
    np.testing.assert_array_equal(mask, (labels >= 1) & (labels < 100))


def test_quiet_noisy_segmenter_equals_ground_truth() -> None:
    rgb, labels = _scene()
    mask = NoisySegmenter(QUIET).segment(rgb, labels, np.random.default_rng(0))
    np.testing.assert_array_equal(mask, _gt(labels))


@pytest.mark.parametrize("name", ["noisy:mild", "noisy:moderate", "noisy:severe"])
def test_noisy_segmenter_is_deterministic_per_seed(name: str) -> None:
    rgb, labels = _scene()
    segmenter = make_segmenter(name)
    first = segmenter.segment(rgb, labels, np.random.default_rng(42))
    again = segmenter.segment(rgb, labels, np.random.default_rng(42))
    other = segmenter.segment(rgb, labels, np.random.default_rng(43))
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    assert first.dtype == bool and first.shape == labels.shape


def test_severity_increases_disagreement() -> None:
    rgb, labels = _scene()
    gt = _gt(labels)
    mean_iou = {}
    for preset in ("mild", "moderate", "severe"):
        segmenter = make_segmenter(f"noisy:{preset}")
        ious = [
            _iou(segmenter.segment(rgb, labels, np.random.default_rng(s)), gt) for s in range(40)
        ]
        mean_iou[preset] = np.mean(ious)
    assert 1.0 > mean_iou["mild"] > mean_iou["moderate"] > mean_iou["severe"] > 0.3


def test_boundary_jitter_moves_only_the_boundary() -> None:
    rgb, labels = _scene()
    gt = _gt(labels)
    config = replace(QUIET, boundary_jitter_px=1.0)
    mask = NoisySegmenter(config).segment(rgb, labels, np.random.default_rng(1))
    changed = mask != gt
    assert changed.any() and (mask & ~gt).any() and (gt & ~mask).any(), "grows and shrinks"
    # The offset field is a smooth N(0, 1 px) field: nothing moves 8 px or more.
    near_edge = cv2.dilate(cv2.Canny(gt.astype(np.uint8) * 255, 1, 1), np.ones((15, 15)))
    assert not np.any(changed & (near_edge == 0))


def test_thin_branches_are_dropped_only_below_the_width_threshold() -> None:
    rgb, labels = _scene()
    config = replace(QUIET, thin_width_px=8.0, thin_drop_prob=1.0)
    mask = NoisySegmenter(config).segment(rgb, labels, np.random.default_rng(0))
    np.testing.assert_array_equal(mask, np.isin(labels, [PRIMARY, THICK_SECONDARY]))
    never = replace(config, thin_drop_prob=0.0)
    mask = NoisySegmenter(never).segment(rgb, labels, np.random.default_rng(0))
    np.testing.assert_array_equal(mask, _gt(labels))


def test_clutter_leaks_only_when_configured() -> None:
    rgb, labels = _scene()
    clutter = labels >= 100
    for seed in range(20):
        mask = NoisySegmenter(QUIET).segment(rgb, labels, np.random.default_rng(seed))
        assert not np.any(mask & clutter)
    always = replace(QUIET, clutter_leak_prob=1.0)
    mask = NoisySegmenter(always).segment(rgb, labels, np.random.default_rng(0))
    np.testing.assert_array_equal(mask, labels > 0)
    sometimes = NoisySegmenter(replace(QUIET, clutter_leak_prob=0.5))
    leaked = [
        (sometimes.segment(rgb, labels, np.random.default_rng(s)) & clutter).any()
        for s in range(20)
    ]
    assert any(leaked) and not all(leaked)


def test_false_blobs_only_add_and_missing_chunks_only_remove() -> None:
    rgb, labels = _scene()
    gt = _gt(labels)
    blobs = NoisySegmenter(replace(QUIET, blob_rate=5.0))
    chunks = NoisySegmenter(replace(QUIET, chunk_rate=5.0))
    added = removed = 0
    for seed in range(10):
        with_blobs = blobs.segment(rgb, labels, np.random.default_rng(seed))
        assert np.all(with_blobs >= gt)
        added += int((with_blobs & ~gt).sum())
        with_holes = chunks.segment(rgb, labels, np.random.default_rng(seed))
        assert np.all(with_holes <= gt)
        removed += int((gt & ~with_holes).sum())
    assert added > 0 and removed > 0


def test_empty_frame_is_handled() -> None:
    labels = np.zeros((HEIGHT, WIDTH), np.int32)
    rgb = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    mask = make_segmenter("noisy:moderate").segment(rgb, labels, np.random.default_rng(0))
    assert mask.shape == labels.shape


def test_make_segmenter_names() -> None:
    assert isinstance(make_segmenter("gt"), GroundTruthSegmenter)
    for name in SEGMENTER_NAMES[1:]:
        assert isinstance(make_segmenter(name), NoisySegmenter)
    assert make_segmenter("noisy:severe").config == NoisySegmenterConfig.preset("severe")
    for bad in ("noisy", "noisy:extreme", "GT", ""):
        with pytest.raises(ValueError, match="valid names"):
            make_segmenter(bad)
    with pytest.raises(ValueError, match="valid presets"):
        NoisySegmenterConfig.preset("extreme")


@pytest.mark.parametrize(
    ("field_name", "value"),
    [
        ("boundary_jitter_px", -1.0),
        ("boundary_jitter_cell_px", 0),
        ("thin_drop_prob", 1.5),
        ("clutter_leak_prob", -0.1),
        ("blob_rate", float("nan")),
        ("blob_axis_range_px", (8.0, 2.0)),
        ("chunk_radius_range_px", (-1.0, 2.0)),
    ],
)
def test_invalid_config_names_the_field(field_name: str, value: object) -> None:
    with pytest.raises(ValueError, match=field_name):
        NoisySegmenterConfig(**{field_name: value})


def test_bad_frames_raise() -> None:
    rgb, labels = _scene()
    rng = np.random.default_rng(0)
    for segmenter in (GroundTruthSegmenter(), NoisySegmenter()):
        with pytest.raises(ValueError, match="rgb"):
            segmenter.segment(rgb[:-1], labels, rng)
        with pytest.raises(ValueError, match="rgb"):
            segmenter.segment(rgb.astype(np.float32), labels, rng)
        with pytest.raises(ValueError, match="labels"):
            segmenter.segment(rgb, labels.astype(np.float32), rng)
        with pytest.raises(ValueError, match="non-negative"):
            segmenter.segment(rgb, labels - 1, rng)
