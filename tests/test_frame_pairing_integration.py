"""Frame pairing for flow-picture segmenters, wired into the simulator's sensing and the replay.

A flow-picture segmenter gets, per frame, the earlier frame that ``FramePairer`` picks by camera
pose (moved >= 7.5 mm and turned < 0.5 deg since) or a recorded flow picture; these tests stand
a spy in for the network (plus one random-init network) and check what reaches it.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from branch_gym.scan import ScanConfig, ScanSession
from branch_gym.sensing import RGBSegmenter, Sensor
from branch_gym.sim.scene.labels import is_scanned_tree
from branch_gym.sim.world import World, WorldConfig
from recon.camera import CameraIntrinsics
from recon.io import ScanFolder, ScanFormatError, open_source
from recon.io.distortion import CameraModel
from recon.io.folder import ScanWriter
from recon.replay import replay
from recon.segmentation import LearnedSegmenter
from recon.segmentation.flow import FramePairingConfig, swap_red_blue
from recon.segmentation.inputs import FlowConfig
from recon.segmentation.network import SegmenterNet, SegmenterNetConfig
from recon.segmentation.weights import save_weights

UP = np.array([0.0, -0.025, 0.0, 0.0, 0.0, 0.0])  # camera twist: 2.5 cm/s up (y points down)
SUBSTEP_S = 1.0 / 60.0  # the robot's sub-step: 0.42 mm up


class SpySegmenter:
    """Stands in for a LearnedSegmenter: records what each call got.

    Args:
        uses_flow: The network reads optical flow.
        uses_flow_picture: It reads the flow as the colour-wheel picture.
        masks: Called with the frame, returns its mask (default: empty).
    """

    source = "<spy>"

    def __init__(self, uses_flow: bool = True, uses_flow_picture: bool = True, masks=None):
        self.uses_flow = uses_flow
        self.uses_flow_picture = uses_flow_picture
        self.masks = masks
        self.calls: list[dict] = []

    def segment(self, rgb, previous_rgb=None, flow_image=None):
        self.calls.append(
            {
                "rgb": rgb.copy(),
                "previous_rgb": None if previous_rgb is None else previous_rgb.copy(),
                "flow_image": None if flow_image is None else flow_image.copy(),
            }
        )
        if self.masks is not None:
            return self.masks(rgb)
        return np.zeros(rgb.shape[:2], bool)


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return a is not None and b is not None and np.array_equal(a, b)


def _random_flow_picture_net() -> SegmenterNet:
    """An untrained RGB + flow-picture network (random weights, seeded)."""
    torch.manual_seed(0)
    return SegmenterNet(SegmenterNetConfig(use_flow=True, flow_picture=True))


# ---------------------------------------------------------------------- sensing
@pytest.fixture(scope="module")
def world():
    world = World(WorldConfig())
    yield world
    world.close()


def _sensor(world: World, spy: SpySegmenter) -> Sensor:
    sensor = Sensor(world, "gt")
    sensor.segmenter = RGBSegmenter(spy)
    world.reset(0)
    sensor.reset(0)
    return sensor


def _move_up(world: World, substeps: int) -> None:
    for _ in range(substeps):
        assert world.apply_camera_twist(UP, SUBSTEP_S).ok


def test_sensing_pairs_frames_by_the_camera_pose(world):
    spy = SpySegmenter()
    sensor = _sensor(world, spy)
    frames, poses = [], []
    for substeps in (0, 7, 12, 7):  # 0, +2.9 mm, +5.0 mm (7.9 from the first), +2.9 mm
        _move_up(world, substeps)
        poses.append(world.T_world_camera)
        frames.append(sensor.capture(0.1 * len(frames)))
    moved_mm = [np.linalg.norm(T[:3, 3] - poses[0][:3, 3]) * 1e3 for T in poses]
    assert moved_mm[1] < 7.5 and moved_mm[2] >= 7.5 and moved_mm[2] - moved_mm[1] < 7.5
    assert moved_mm[3] - moved_mm[1] >= 7.5 and moved_mm[3] - moved_mm[2] < 7.5
    assert not np.array_equal(frames[0].rgb, frames[1].rgb)

    assert all(np.array_equal(c["rgb"], f.rgb) for c, f in zip(spy.calls, frames, strict=True))
    assert spy.calls[0]["previous_rgb"] is None  # nothing earlier
    assert spy.calls[1]["previous_rgb"] is None  # 2.9 mm: too close to the first frame
    assert _same(spy.calls[2]["previous_rgb"], frames[0].rgb)  # 7.9 mm from the first
    assert _same(spy.calls[3]["previous_rgb"], frames[1].rgb)  # the most recent far enough
    assert all(c["flow_image"] is None for c in spy.calls)

    sensor.reset(0)  # a new scan forgets the history
    sensor.capture(0.0)
    assert spy.calls[-1]["previous_rgb"] is None and len(sensor.segmenter.pairer) == 1


def test_unsegmented_frames_still_enter_the_pairing_history(world):
    spy = SpySegmenter()
    sensor = _sensor(world, spy)
    first = sensor.capture(0.0, segment=False)
    assert spy.calls == [] and not first.mask.any()
    assert len(sensor.segmenter.pairer) == 1
    _move_up(world, 19)  # 7.9 mm
    sensor.capture(0.1)
    assert _same(spy.calls[0]["previous_rgb"], first.rgb)


def test_older_networks_keep_their_inputs(world):
    vectors = SpySegmenter(uses_flow_picture=False)  # the old flow-vector design
    sensor = _sensor(world, vectors)
    assert sensor.segmenter.pairer is None
    sensor.capture(0.0)
    _move_up(world, 1)  # 0.4 mm: no pairing rule, the previous frame
    middle = sensor.capture(0.1, segment=False)
    _move_up(world, 1)
    sensor.capture(0.2)
    assert vectors.calls[0]["previous_rgb"] is None
    assert _same(vectors.calls[1]["previous_rgb"], middle.rgb)  # rendered, not segmented

    colours = SpySegmenter(uses_flow=False, uses_flow_picture=False)
    sensor = _sensor(world, colours)
    for k in range(3):
        _move_up(world, 19)
        sensor.capture(0.1 * k)
    assert all(c["previous_rgb"] is None for c in colours.calls)


def test_a_flow_picture_network_needs_the_pose(world):
    segmenter = RGBSegmenter(SpySegmenter())
    with pytest.raises(ValueError, match="pass T_world_camera"):
        segmenter.segment(np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.int32), None)


def test_scan_config_sets_the_pairing(tmp_path):
    with pytest.raises(ValueError, match="frame_pairing must be a FramePairingConfig"):
        ScanConfig(frame_pairing={"min_translation_m": 0.01})
    with pytest.raises(ValueError, match="history_travel_m"):
        ScanConfig(frame_pairing=FramePairingConfig(min_translation_m=0.1))
    weights = save_weights(tmp_path / "flow_picture.pt", _random_flow_picture_net(), FlowConfig())
    pairing = FramePairingConfig(min_translation_m=0.002, max_rotation_deg=1.0)
    session = ScanSession(ScanConfig(segmenter=f"learned:{weights}", frame_pairing=pairing))
    try:
        assert session.sensor.segmenter.segmenter.uses_flow_picture
        assert session.sensor.segmenter.pairer.config == pairing
    finally:
        session.close()


def _short_scan(listener: bool) -> tuple[ScanSession, SpySegmenter, list]:
    """A 3.5 cm scan of tree 0 through a spy that returns the exact masks."""
    session = ScanSession(ScanConfig(end_height_m=0.31))
    world = session.world
    spy = SpySegmenter(masks=lambda rgb: is_scanned_tree(world.render().labels))
    session.sensor.segmenter = RGBSegmenter(spy)
    fed: list = []
    if listener:
        session.frame_listeners.append(fed.append)
    session.reset(0)
    while not session.done:
        session.step(0.0)
    session.close()
    return session, spy, fed


def test_a_scan_segments_only_the_frames_its_iterations_read():
    session, spy, _ = _short_scan(listener=False)
    n_rendered = session.sensor.visibility.frames
    assert len(session.reports) >= 2
    assert len(spy.calls) == len(session.reports) < n_rendered / 4
    paired = sum(c["previous_rgb"] is not None for c in spy.calls)
    assert paired >= len(spy.calls) - 1  # each iteration frame is >= 10 mm after the last

    # With a listener (a recording) every frame is segmented; the iterations see the same.
    recorded, spy_all, fed = _short_scan(listener=True)
    assert len(spy_all.calls) == len(fed) == recorded.sensor.visibility.frames == n_rendered
    assert recorded.model.to_dict() == session.model.to_dict()
    assert [r.outcome for r in recorded.reports] == [r.outcome for r in session.reports]
    partners = {c["rgb"].tobytes(): c["previous_rgb"] for c in spy_all.calls}
    for call in spy.calls:
        partner = partners[call["rgb"].tobytes()]
        assert (partner is None and call["previous_rgb"] is None) or _same(
            partner, call["previous_rgb"]
        )


# ---------------------------------------------------------------------- replay
W, H = 64, 48
STEP_M = 0.003  # camera travel between recorded frames: frame k pairs with frame k - 3
N_FRAMES = 12
INTRINSICS = CameraIntrinsics(W, H, 60.0, 60.0, W / 2, H / 2)


def _image(k: int) -> np.ndarray:
    return np.random.default_rng(k).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _picture(k: int, size=(W, H)) -> np.ndarray:
    return np.random.default_rng(100 + k).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)


def _pose(k: int) -> np.ndarray:
    T = np.eye(4)
    T[1, 3] = -STEP_M * k  # up (camera y points down), no turn
    return T


def _write_scan(path: Path, pictures: dict[int, np.ndarray] | None = None) -> Path:
    pictures = pictures or {}
    with ScanWriter(path, CameraModel(INTRINSICS)) as writer:
        for k in range(N_FRAMES):
            writer.add(0.1 * k, _pose(k), _image(k), flow_image=pictures.get(k))
    return path


def _stripe(rgb: np.ndarray) -> np.ndarray:
    mask = np.zeros(rgb.shape[:2], bool)
    mask[:, W // 2 - 3 : W // 2 + 3] = True
    return mask


# Frames 4 and 7 carry a picture named in frames.jsonl (7's at half size), 9 one beside its image.
RECORDED = {4: _picture(4), 7: _picture(7, (W // 2, H // 2))}
BESIDE = 9


@pytest.fixture(scope="module")
def flow_scan(tmp_path_factory) -> Path:
    scan = _write_scan(tmp_path_factory.mktemp("flow") / "scan", RECORDED)
    beside = scan / "images" / f"{BESIDE:06d}_flow.png"
    assert cv2.imwrite(str(beside), cv2.cvtColor(_picture(BESIDE), cv2.COLOR_RGB2BGR))
    return scan


def _expected_pictures() -> dict[int, np.ndarray]:
    expected = dict(RECORDED)
    expected[7] = cv2.resize(RECORDED[7], (W, H), interpolation=cv2.INTER_AREA)
    expected[BESIDE] = _picture(BESIDE)
    return expected


def _check_calls(spy: SpySegmenter, pictures: dict[int, np.ndarray]) -> None:
    assert len(spy.calls) == N_FRAMES
    for k, call in enumerate(spy.calls):
        assert np.array_equal(call["rgb"], _image(k))
        if k in pictures:
            assert np.array_equal(call["flow_image"], pictures[k]), k
            assert call["previous_rgb"] is None, k
        else:
            assert call["flow_image"] is None, k
            partner = call["previous_rgb"]
            if k < 3:  # less than 7.5 mm from every earlier frame
                assert partner is None, k
            else:  # 9 mm back; a frame with a picture is a partner too
                assert _same(partner, _image(k - 3)), k


def test_replay_pairs_recorded_frames_by_pose(tmp_path):
    scan = _write_scan(tmp_path / "scan")
    spy = SpySegmenter(masks=_stripe)
    result = replay(scan, tmp_path / "out", segmenter=spy, progress=False)
    _check_calls(spy, {})
    assert result.flow_inputs == {"none": 3, "paired": N_FRAMES - 3}
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["flow_inputs"] == result.flow_inputs


def test_replay_passes_recorded_flow_pictures(flow_scan, tmp_path):
    spy = SpySegmenter(masks=_stripe)
    result = replay(flow_scan, tmp_path / "out", segmenter=spy, progress=False)
    expected = _expected_pictures()
    _check_calls(spy, expected)
    assert result.flow_inputs == {"none": 3, "recorded": 3, "paired": N_FRAMES - 6}

    swapped = SpySegmenter(masks=_stripe)
    replay(
        flow_scan, tmp_path / "swapped", segmenter=swapped, progress=False,
        flow_red_blue_swapped=True,
    )  # fmt: skip
    _check_calls(swapped, {k: swap_red_blue(p) for k, p in expected.items()})


def test_replay_gives_other_segmenters_the_previous_frame(flow_scan, tmp_path):
    spy = SpySegmenter(uses_flow_picture=False, masks=_stripe)
    result = replay(flow_scan, tmp_path / "out", segmenter=spy, progress=False)
    assert spy.calls[0]["previous_rgb"] is None
    for k, call in enumerate(spy.calls[1:], start=1):
        assert _same(call["previous_rgb"], _image(k - 1)) and call["flow_image"] is None
    assert result.flow_inputs == {}


def test_replay_through_a_flow_picture_network(flow_scan, tmp_path):
    result = replay(
        flow_scan,
        tmp_path / "out",
        segmenter=LearnedSegmenter(_random_flow_picture_net()),
        progress=False,
    )
    assert result.n_fed == N_FRAMES
    assert result.flow_inputs == {"none": 3, "recorded": 3, "paired": N_FRAMES - 6}


def test_a_named_flow_picture_that_is_missing(tmp_path):
    scan = tmp_path / "scan"
    _write_scan(scan, RECORDED)
    (scan / "flow" / "000004.png").unlink()
    assert len(list(ScanFolder(scan).frames())) == N_FRAMES  # not read without a flow segmenter
    with pytest.raises(ScanFormatError, match=r"cannot read flow picture .*000004\.png"):
        list(ScanFolder(scan).frames(load_flow=True))
    frames = list(ScanFolder(scan, skip_bad_frames=True).frames(load_flow=True))
    assert [f.flow_image is not None for f in frames] == [k == 7 for k in range(N_FRAMES)]
    assert all(f.skip_reason is None for f in frames)


def test_bag_flow_topic(flow_scan, tmp_path):
    pytest.importorskip("rosbags")
    from replay_fixtures import write_bag

    from recon.io.rosbag import BagConfig, BagSource

    write_bag(flow_scan, tmp_path / "bag", mask_topic=None, flow_topic="/flow_image")
    with pytest.raises(ScanFormatError, match=r"topic '/camera/flow' is absent"):
        BagSource(tmp_path / "bag", BagConfig(mask_topic=None, flow_topic="/camera/flow"))
    config = BagConfig(mask_topic=None, flow_topic="/flow_image")
    spy = SpySegmenter(masks=_stripe)
    replay(open_source(tmp_path / "bag", config), tmp_path / "out", segmenter=spy, progress=False)
    _check_calls(spy, _expected_pictures())
