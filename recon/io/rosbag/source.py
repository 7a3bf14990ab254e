"""The bag as a scan source: :class:`BagSource` opens a recording and yields its frames.

Opening reads the calibration, the transforms (or the pose topic) and the stamps of the masks
and flow pictures; :meth:`BagSource.frames` then decodes the images in stamp order
(``recon/io/rosbag/decoding.py``), each with its pose (``transforms.py``) and the mask and flow
picture matched to it (``sync.py``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from recon.camera import CameraIntrinsics
from recon.io.distortion import CameraModel, Undistorter
from recon.io.folder import LoadedFrame, ScanFormatConfig, ScanFormatError
from recon.io.rosbag.config import BagConfig
from recon.io.rosbag.decoding import FrameDecoder, camera_from_info, stamp_ns
from recon.io.rosbag.sync import PendingFrames, StampIndex
from recon.io.rosbag.transforms import TransformSeries, TransformTree

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
BAG_SUFFIXES = (".db3", ".mcap", ".bag")


def require_rosbags():
    """Import ``rosbags`` or raise an ImportError that says how to install it."""
    try:
        import rosbags.highlevel
        import rosbags.typesys
    except ImportError as error:
        raise ImportError(
            "reading ROS bags needs the optional 'rosbags' package: "
            "pip install 'branch_gym[rosbag]' (or: pip install 'rosbags>=0.10')"
        ) from error
    return rosbags


def is_bag(path: str | Path) -> bool:
    """A rosbag2 folder (``metadata.yaml``) or a bag file (.db3, .mcap, .bag)."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix in BAG_SUFFIXES


class BagSource:
    """A ROS 2 (or ROS 1) bag read as a scan source (the same interface as ``ScanFolder``).

    Opening reads the calibration, the transforms (or the pose topic) and the mask stamps;
    :meth:`frames` then decodes the images in stamp order.

    Args:
        path: A rosbag2 folder (``metadata.yaml`` + ``.db3`` or ``.mcap``), a file inside one,
            or a ROS 1 ``.bag`` file.
        config: Topics, frames and tolerances.
        format_config: Pose and mask tolerances shared with the folder format.

    Raises:
        ImportError: ``rosbags`` is not installed.
        ScanFormatError: an absent or empty topic, no calibration, no transform chain, a
            non-monotonic image stream, or an image size that disagrees with the calibration.
    """

    def __init__(
        self,
        path: str | Path,
        config: BagConfig | None = None,
        format_config: ScanFormatConfig | None = None,
    ) -> None:
        rosbags = require_rosbags()
        from rosbags.typesys import Stores, get_typestore

        self.config = config or BagConfig()
        self.format_config = format_config or ScanFormatConfig()
        path = Path(path)
        if not path.exists():
            raise ScanFormatError(f"{path}: bag not found")
        if path.is_file() and path.suffix in (".db3", ".mcap"):
            path = path.parent
        self.path = path
        try:
            self._typestore = get_typestore(Stores(self.config.typestore))
        except ValueError:
            raise ValueError(f"unknown rosbags type store {self.config.typestore!r}") from None
        self._reader_cls = rosbags.highlevel.AnyReader
        self.metadata: dict = {"source": "rosbag", "path": str(path)}
        self.skipped_at_open = 0
        with self._open() as reader:
            self._read_static_part(reader)

    # ------------------------------------------------------------------ interface
    @property
    def name(self) -> str:
        return str(self.path)

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._decoder.intrinsics

    @property
    def undistorter(self) -> Undistorter:
        """The undistortion of the calibration's images."""
        return self._decoder.undistorter

    @property
    def has_masks(self) -> bool:
        return self.config.mask_topic is not None

    @property
    def frames_without_mask(self) -> list[int]:
        return [] if self.has_masks else list(range(self.n_images))

    def __len__(self) -> int:
        return self.n_images

    def truth_path(self) -> Path | None:
        return None

    # ------------------------------------------------------------------ opening
    def _open(self):
        try:
            reader = self._reader_cls([self.path], default_typestore=self._typestore)
            reader.open()
        except Exception as error:  # rosbags raises its own error types per format
            raise ScanFormatError(f"{self.path}: cannot open bag ({error})") from None
        return _Closing(reader)

    def _topic(self, reader, topic: str, types: tuple[str, ...], required: bool = True):
        """The connections of ``topic``, checked for presence, type and messages."""
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            if not required:
                return []
            available = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
            raise ScanFormatError(
                f"{self.path}: topic {topic!r} is absent (topics in the bag: {available})"
            )
        for c in connections:
            if c.msgtype not in types:
                raise ScanFormatError(
                    f"{self.path}: topic {topic!r} has type {c.msgtype}, expected one of {types}"
                )
        if sum(c.msgcount for c in connections) == 0 and required:
            raise ScanFormatError(f"{self.path}: topic {topic!r} has no messages")
        return connections

    def _read_static_part(self, reader) -> None:
        cfg = self.config
        self._image_connections = self._topic(reader, cfg.image_topic, IMAGE_TYPES)
        self.n_images = sum(c.msgcount for c in self._image_connections)
        info_connections = self._topic(reader, cfg.camera_info_topic, (CAMERA_INFO_TYPE,))
        self._mask_connections = []
        if cfg.mask_topic is not None:
            self._mask_connections = self._topic(reader, cfg.mask_topic, IMAGE_TYPES)
        flow_connections = []
        if cfg.flow_topic is not None:
            flow_connections = self._topic(reader, cfg.flow_topic, IMAGE_TYPES)
        self.tf = TransformTree()
        pose_samples: list = []
        pose_parent: str | None = None
        wanted = list(info_connections) + list(self._mask_connections) + flow_connections
        if cfg.pose_topic is not None:
            wanted += self._topic(reader, cfg.pose_topic, (POSE_TYPE,))
        else:
            tf = self._topic(reader, cfg.tf_topic, (TF_TYPE,), required=False)
            static = self._topic(reader, cfg.tf_static_topic, (TF_TYPE,), required=False)
            if not tf and not static:
                available = ", ".join(sorted({c.topic for c in reader.connections}))
                raise ScanFormatError(
                    f"{self.path}: neither {cfg.tf_topic!r} nor {cfg.tf_static_topic!r} is in "
                    f"the bag (topics: {available}); set pose_topic for a PoseStamped topic"
                )
            if sum(c.msgcount for c in tf + static) == 0:
                raise ScanFormatError(
                    f"{self.path}: topics {cfg.tf_topic!r} and {cfg.tf_static_topic!r} are empty"
                )
            wanted += tf + static
        self.camera: CameraModel | None = None
        self._mask_stamps: list[int] = []
        flow_stamps: list[int] = []
        for connection, t_bag, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, connection.msgtype)
            topic = connection.topic
            if topic == cfg.camera_info_topic:
                if self.camera is None:
                    self.camera = camera_from_info(msg, f"{self.path}: topic {topic!r}")
            elif topic == cfg.mask_topic:
                self._mask_stamps.append(stamp_ns(msg.header, t_bag))
            elif topic == cfg.flow_topic:
                flow_stamps.append(stamp_ns(msg.header, t_bag))
            elif topic == cfg.pose_topic:
                p, o = msg.pose.position, msg.pose.orientation
                pose_parent = msg.header.frame_id.lstrip("/")
                pose_samples.append(
                    (stamp_ns(msg.header, t_bag), (p.x, p.y, p.z), (o.x, o.y, o.z, o.w))
                )
            else:
                static = topic == cfg.tf_static_topic
                for ts in msg.transforms:
                    tr, q = ts.transform.translation, ts.transform.rotation
                    self.tf.add(
                        ts.header.frame_id,
                        ts.child_frame_id,
                        stamp_ns(ts.header, t_bag),
                        (tr.x, tr.y, tr.z),
                        (q.x, q.y, q.z, q.w),
                        static,
                    )
        assert self.camera is not None
        self._decoder = FrameDecoder(
            str(self.path), self.camera, cfg.camera_info_topic, self.format_config.mask_threshold
        )
        self._pose_series: TransformSeries | None = None
        if cfg.pose_topic is not None:
            self._pose_series = TransformSeries.from_samples(
                pose_parent or cfg.world_frame, cfg.camera_frame, pose_samples
            )
            self.metadata["pose_source"] = f"{cfg.pose_topic} (frame {pose_parent})"
        else:
            self.tf.finalize()
            topics = f"{cfg.tf_topic} + {cfg.tf_static_topic}"
            self.tf.check_chain(cfg.world_frame.lstrip("/"), cfg.camera_frame.lstrip("/"), topics)
            self.metadata["pose_source"] = f"{topics}: {cfg.world_frame} -> {cfg.camera_frame}"
        self._mask_stamps_index = StampIndex(self._mask_stamps)
        self._flow_stamps_index = StampIndex(flow_stamps)
        self.metadata["camera"] = self.camera.to_dict()

    # ------------------------------------------------------------------ frames
    def pose_at(self, t_ns: int) -> tuple[np.ndarray | None, str | None]:
        """T_world_camera at ``t_ns``, or (None, reason)."""
        cfg = self.config
        tol = round(cfg.pose_tolerance_s * 1e9)
        gap = round(cfg.max_interpolation_gap_s * 1e9)
        if self._pose_series is not None:
            return self._pose_series.at(t_ns, tol, gap)
        world, camera = cfg.world_frame.lstrip("/"), cfg.camera_frame.lstrip("/")
        return self.tf.lookup(world, camera, t_ns, tol, gap)

    def _mask_index(self, t_ns: int) -> int | None:
        """Index (in bag order) of the mask stamped nearest ``t_ns`` within the tolerance."""
        return self._mask_stamps_index.nearest(t_ns, self.config.mask_tolerance_s)

    def _flow_index(self, t_ns: int) -> int | None:
        """Index (in bag order) of the flow picture stamped nearest ``t_ns`` within tolerance."""
        return self._flow_stamps_index.nearest(t_ns, self.config.flow_tolerance_s)

    def frames(self, load_masks: bool = True, load_flow: bool = False) -> Iterator[LoadedFrame]:
        """Decode the images in order, with pose and mask (see :class:`LoadedFrame`).

        Args:
            load_masks: Read the mask topic (False when a segmenter replaces the masks).
            load_flow: Read the flow topic (``BagConfig.flow_topic``, if set) into
                :attr:`LoadedFrame.flow_image`; an image with no picture within
                ``flow_tolerance_s`` keeps none.

        Raises:
            ScanFormatError: image stamps going back in time, an undecodable image or one whose
                size disagrees with the CameraInfo, or a flow picture that is not colour.
        """
        cfg = self.config
        load_masks = load_masks and self.has_masks
        load_flow = load_flow and cfg.flow_topic is not None
        pending = PendingFrames()
        topics = {cfg.image_topic} | ({cfg.mask_topic} if load_masks else set())
        topics |= {cfg.flow_topic} if load_flow else set()
        index, mask_count, flow_count = 0, 0, 0
        last_ns: int | None = None
        with self._open() as reader:  # connections belong to their reader: select them anew
            connections = [c for c in reader.connections if c.topic in topics]
            for connection, t_bag, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, connection.msgtype)
                t_ns = stamp_ns(msg.header, t_bag)
                if connection.topic == cfg.mask_topic and load_masks:
                    where = f"topic {cfg.mask_topic!r} message {mask_count}"
                    pending.masks[mask_count] = self._decoder.mask(msg, connection.msgtype, where)
                    mask_count += 1
                elif connection.topic == cfg.flow_topic and load_flow:
                    where = f"topic {cfg.flow_topic!r} message {flow_count}"
                    picture = self._decoder.flow_picture(msg, connection.msgtype, where)
                    pending.flows[flow_count] = picture
                    flow_count += 1
                else:
                    where = f"topic {cfg.image_topic!r} message {index}"
                    if last_ns is not None and t_ns < last_ns:
                        raise ScanFormatError(
                            f"{self.path}: {where}: stamp {t_ns * 1e-9:.6f} s is before the "
                            f"previous image's {last_ns * 1e-9:.6f} s: times must increase"
                        )
                    duplicate = last_ns is not None and t_ns == last_ns
                    frame = LoadedFrame(index, t_ns * 1e-9, where)
                    mask, flow = self._read_image(
                        frame, t_ns, msg, connection.msgtype, duplicate, load_masks, load_flow
                    )
                    pending.wait(frame, mask, flow)
                    last_ns = t_ns
                    index += 1
                yield from pending.ready()
            yield from pending.rest(cfg.mask_topic)  # masks or pictures that never arrived

    def _read_image(
        self, frame: LoadedFrame, t_ns: int, msg, msgtype: str, duplicate: bool,
        load_masks: bool, load_flow: bool,
    ) -> tuple[int, int]:  # fmt: skip
        """Fill the frame of the image message stamped ``t_ns`` (pose, RGB) or skip it; the bag
        indices of the mask and flow picture it needs (-1: none)."""
        cfg = self.config
        if duplicate:
            frame.skip("duplicate image stamp", "duplicate image stamp")
            return -1, -1
        T, reason = self.pose_at(t_ns)
        if T is None:
            frame.skip("no pose", f"no pose: {reason}")
            return -1, -1
        frame.T_world_camera = T
        frame.rgb = self._decoder.image(msg, msgtype, frame.where)
        mask = flow = -1
        if load_masks:
            found = self._mask_index(t_ns)
            if found is None:
                reason = f"no mask on {cfg.mask_topic!r} within {cfg.mask_tolerance_s:g} s"
                frame.skip("no mask", reason)
            else:
                mask = found
        if load_flow and frame.skip_reason is None:
            picture = self._flow_index(t_ns)
            flow = -1 if picture is None else picture
        return mask, flow


class _Closing:
    """Context manager closing a rosbags reader."""

    def __init__(self, reader) -> None:
        self.reader = reader

    def __enter__(self):
        return self.reader

    def __exit__(self, *exc) -> None:
        self.reader.close()
