"""ROS 2 bags (sqlite3 ``.db3`` or ``.mcap``) as a scan source, with the pure-Python ``rosbags``.

No ROS install is needed: ``pip install 'branch_gym[rosbag]'`` (or ``pip install rosbags``). This is
the only module that imports ``rosbags``, and only when a bag is opened.

What is read (topic and frame names are :class:`BagConfig` fields; the defaults are the paper
authors' recordings, reference.md):

* images: ``sensor_msgs/msg/Image`` (rgb8, bgr8, rgba8, bgra8, mono8, mono16) or
  ``sensor_msgs/msg/CompressedImage`` (JPEG/PNG), time = header stamp;
* the calibration: the first ``sensor_msgs/msg/CameraInfo`` (K, D, distortion model); images and
  masks are undistorted when D is non-zero;
* camera poses: ``/tf`` + ``/tf_static`` chained from ``world_frame`` (``base_link``) to
  ``camera_frame`` (``camera_color_optical_frame``, OpenCV axes), each dynamic transform
  interpolated to the image time (linear translation, slerp rotation); or a
  ``geometry_msgs/msg/PoseStamped`` topic (the camera optical frame's pose in its header frame);
* masks: an image topic (the authors record ``/image_mask``), matched to images by stamp; or none
  (then a segmenter makes them, see ``recon.replay``);
* optical-flow pictures (optional, ``flow_topic``): an image topic of colour-wheel pictures
  (Image rgb8/bgr8/rgba8/bgra8, decoded to RGB by the encoding, or CompressedImage), matched to
  images by stamp; resized to the image (``cv2.INTER_AREA``) and undistorted like it. An image
  without a picture is not skipped: it has none (a segmenter then pairs frames instead).

A frame whose pose cannot be interpolated within the tolerances, or with no matching mask, is
yielded as skipped with the reason (the replay counts and reports it).
"""

from __future__ import annotations

import argparse
import logging
import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from recon.camera import CameraIntrinsics, invert_pose
from recon.io.distortion import CameraModel, Undistorter, canonical_distortion_model
from recon.io.folder import (
    LoadedFrame,
    ScanFormatConfig,
    ScanFormatError,
    flow_picture_from_array,
    mask_from_array,
)

logger = logging.getLogger(__name__)

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPE = "geometry_msgs/msg/PoseStamped"
BAG_SUFFIXES = (".db3", ".mcap", ".bag")


@dataclass(frozen=True)
class BagConfig:
    """Topics, frames and tolerances of a bag recording.

    Attributes:
        image_topic: Colour images (Image or CompressedImage).
        camera_info_topic: The camera's CameraInfo.
        tf_topic: Dynamic transforms (TFMessage).
        tf_static_topic: Static transforms (TFMessage).
        world_frame: The world (robot base) frame the poses are expressed in.
        camera_frame: The camera's optical frame (x right, y down, z forward).
        pose_topic: A PoseStamped topic of the camera optical frame used instead of TF, or None.
        mask_topic: Branch masks (Image or CompressedImage; non-zero = branch), or None.
        pose_tolerance_s: An image outside the time span of a transform's samples takes the
            nearest sample if it is at most this far (our choice: 50 ms, ~1 mm at 2.5 cm/s).
        max_interpolation_gap_s: Samples further apart than this are not interpolated between.
        mask_tolerance_s: A mask belongs to the image whose stamp is within this (masks are
            stamped with their image's header by the authors' segmenter).
        typestore: rosbags type store for bags without message definitions.
        flow_topic: Optical-flow pictures of the images (Image or CompressedImage, colour
            wheel), or None (default: none recorded). Read only when a segmenter uses them.
        flow_tolerance_s: A flow picture belongs to the image whose stamp is within this (our
            choice: as ``mask_tolerance_s``, pictures stamped with their image's header).
    """

    image_topic: str = "/camera/color/image_raw"
    camera_info_topic: str = "/camera/color/camera_info"
    tf_topic: str = "/tf"
    tf_static_topic: str = "/tf_static"
    world_frame: str = "base_link"
    camera_frame: str = "camera_color_optical_frame"
    pose_topic: str | None = None
    mask_topic: str | None = "/image_mask"
    pose_tolerance_s: float = 0.05
    max_interpolation_gap_s: float = 0.5
    mask_tolerance_s: float = 0.005
    typestore: str = "ros2_humble"
    flow_topic: str | None = None
    flow_tolerance_s: float = 0.005

    def __post_init__(self) -> None:
        names = ("pose_tolerance_s", "max_interpolation_gap_s", "mask_tolerance_s")
        for name in (*names, "flow_tolerance_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"BagConfig.{name} must be >= 0, got {value}")


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


# ---------------------------------------------------------------------- transforms
def quaternion_slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (x, y, z, w) at fraction ``a``."""
    q0 = q0 / np.linalg.norm(q0)
    q1 = q1 / np.linalg.norm(q1)
    d = float(q0 @ q1)
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
    else:
        theta = math.acos(d)
        q = (math.sin((1 - a) * theta) * q0 + math.sin(a * theta) * q1) / math.sin(theta)
    return q / np.linalg.norm(q)


def pose_matrix(translation: np.ndarray, quaternion_xyzw: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a (3,) translation and a (4,) quaternion (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(quaternion_xyzw, float)).as_matrix()
    T[:3, 3] = translation
    return T


@dataclass
class TransformSeries:
    """Time samples of one transform parent -> child (the child's pose in the parent).

    Attributes:
        parent: Parent frame id.
        child: Child frame id.
        times_ns: (N,) sample times, ns, increasing.
        translations: (N, 3) metres.
        quaternions: (N, 4) unit quaternions (x, y, z, w).
    """

    parent: str
    child: str
    times_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    translations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    quaternions: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))

    @classmethod
    def from_samples(cls, parent: str, child: str, samples: list) -> TransformSeries:
        """From (t_ns, (3,), (4,)) samples in any order; a repeated time keeps the last one."""
        by_time = {int(t): (tr, q) for t, tr, q in samples}
        times = np.array(sorted(by_time), dtype=np.int64)
        return cls(
            parent,
            child,
            times,
            np.array([by_time[t][0] for t in times], float).reshape(-1, 3),
            np.array([by_time[t][1] for t in times], float).reshape(-1, 4),
        )

    def at(
        self, t_ns: int, tolerance_ns: int, max_gap_ns: int
    ) -> tuple[np.ndarray | None, str | None]:
        """The (4, 4) transform at ``t_ns``, interpolated; or (None, reason)."""
        times = self.times_ns
        if len(times) == 0:
            return None, f"no samples of {self.parent} -> {self.child}"
        i = int(np.searchsorted(times, t_ns))
        if i < len(times) and times[i] == t_ns:
            return pose_matrix(self.translations[i], self.quaternions[i]), None
        if i == 0 or i == len(times):
            j = 0 if i == 0 else len(times) - 1
            off = abs(int(times[j]) - t_ns)
            if off <= tolerance_ns:
                return pose_matrix(self.translations[j], self.quaternions[j]), None
            return None, (
                f"no transform {self.parent} -> {self.child} within {tolerance_ns / 1e9:g} s "
                f"(nearest sample {off / 1e9:.3f} s away)"
            )
        t0, t1 = int(times[i - 1]), int(times[i])
        if t1 - t0 > max_gap_ns:
            return None, (
                f"transform {self.parent} -> {self.child} has a {(t1 - t0) / 1e9:.3f} s gap "
                f"around the image time (max {max_gap_ns / 1e9:g} s)"
            )
        a = (t_ns - t0) / (t1 - t0)
        translation = (1 - a) * self.translations[i - 1] + a * self.translations[i]
        q = quaternion_slerp(self.quaternions[i - 1], self.quaternions[i], a)
        return pose_matrix(translation, q), None


class TransformTree:
    """TF frames: static and dynamic transforms, chained between any two connected frames."""

    def __init__(self) -> None:
        self._samples: dict[tuple[str, str], list] = {}
        self._static: dict[tuple[str, str], np.ndarray] = {}
        self.dynamic: dict[str, TransformSeries] = {}
        self.parents: dict[str, str] = {}

    def add(self, parent: str, child: str, t_ns: int, translation, quaternion, static: bool):
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if static:
            self._static[(parent, child)] = pose_matrix(translation, quaternion)
        else:
            self._samples.setdefault((parent, child), []).append((t_ns, translation, quaternion))

    def finalize(self) -> None:
        """Index the transforms by child frame (call after the last :meth:`add`)."""
        self.dynamic = {
            child: TransformSeries.from_samples(parent, child, samples)
            for (parent, child), samples in self._samples.items()
        }
        self.parents = {child: parent for parent, child in self._static}
        for (parent, child), _ in self._samples.items():
            if child in self.parents and self.parents[child] != parent:
                logger.warning("frame %s has two parents (%s, %s)", child, parent, child)
            self.parents[child] = parent

    @property
    def frames(self) -> set[str]:
        return set(self.parents) | set(self.parents.values())

    def _ancestors(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self.parents and len(chain) <= len(self.parents) + 1:
            chain.append(self.parents[chain[-1]])
        return chain

    def check_chain(self, world: str, camera: str, topics: str) -> None:
        """Raise :class:`ScanFormatError` unless ``world`` and ``camera`` are connected."""
        for frame in (world, camera):
            if frame not in self.frames:
                raise ScanFormatError(
                    f"frame {frame!r} appears in no transform of {topics} "
                    f"(frames there: {sorted(self.frames) or 'none'})"
                )
        if not set(self._ancestors(world)) & set(self._ancestors(camera)):
            raise ScanFormatError(
                f"no transform chain between {world!r} and {camera!r} in {topics}: "
                f"{' -> '.join(self._ancestors(camera))} and {' -> '.join(self._ancestors(world))}"
            )

    def _root_to(self, frame: str, root: str, t_ns: int, tol: int, gap: int):
        """T_root_frame at t (product down the chain), or (None, reason)."""
        T = np.eye(4)
        f = frame
        while f != root:
            parent = self.parents[f]
            if f in self.dynamic and self.dynamic[f].parent == parent:
                edge, reason = self.dynamic[f].at(t_ns, tol, gap)
                if edge is None:
                    return None, reason
            else:
                edge = self._static[(parent, f)]
            T = edge @ T
            f = parent
        return T, None

    def lookup(
        self, world: str, camera: str, t_ns: int, tolerance_ns: int, max_gap_ns: int
    ) -> tuple[np.ndarray | None, str | None]:
        """T_world_camera at ``t_ns`` (see :meth:`check_chain`), or (None, reason)."""
        up_world = self._ancestors(world)
        common = next(f for f in self._ancestors(camera) if f in set(up_world))
        T_root_camera, reason = self._root_to(camera, common, t_ns, tolerance_ns, max_gap_ns)
        if T_root_camera is None:
            return None, reason
        T_root_world, reason = self._root_to(world, common, t_ns, tolerance_ns, max_gap_ns)
        if T_root_world is None:
            return None, reason
        return invert_pose(T_root_world) @ T_root_camera, None


# ---------------------------------------------------------------------- messages
def stamp_ns(header, fallback_ns: int) -> int:
    """Header stamp in ns (the bag's receive time when the stamp is zero)."""
    t = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return t if t > 0 else int(fallback_ns)


def decode_image(msg, msgtype: str) -> np.ndarray:
    """(H, W, 3) RGB uint8, or (H, W) for mono images, from an Image or CompressedImage.

    Raises:
        ValueError: an unsupported encoding or undecodable data.
    """
    if msgtype.endswith("CompressedImage"):
        data = np.frombuffer(bytes(msg.data), np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"cannot decode compressed image (format {msg.format!r})")
        if image.ndim == 3:
            code = cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB
            image = cv2.cvtColor(image, code)
        return image
    encoding = msg.encoding.lower()
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3}
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    raw = np.frombuffer(bytes(msg.data), np.uint8)
    if encoding in ("mono16", "16uc1"):
        dtype = np.dtype(">u2" if msg.is_bigendian else "<u2")
        rows = raw[: h * step].reshape(h, step)[:, : 2 * w].copy()
        return rows.view(dtype).reshape(h, w).astype(np.uint16)
    if encoding not in channels:
        raise ValueError(f"unsupported image encoding {msg.encoding!r}")
    c = channels[encoding]
    if len(raw) < h * step or step < w * c:
        raise ValueError(f"image data too short for {w}x{h} {msg.encoding} (step {step})")
    image = raw[: h * step].reshape(h, step)[:, : w * c].reshape(h, w, c)
    if c == 1:
        return image[..., 0].copy()
    if encoding in ("bgr8", "8uc3"):
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if encoding == "bgra8":
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    if encoding == "rgba8":
        return image[..., :3].copy()
    return image.copy()


def camera_from_info(msg, where: str) -> CameraModel:
    """A :class:`CameraModel` from a CameraInfo message (K, D, distortion model, size)."""
    K = np.asarray(msg.k, float).reshape(3, 3)
    if not np.any(K):
        raise ScanFormatError(f"{where}: K is all zeros (camera not calibrated)")
    coeffs = tuple(float(c) for c in np.asarray(msg.d, float))
    name = msg.distortion_model or ("plumb_bob" if coeffs else "none")
    try:
        model = canonical_distortion_model(name)
        if not any(coeffs):
            model, coeffs = "none", ()
        elif model == "plumb_bob" and len(coeffs) > 5:  # some drivers pad D with zeros
            if any(coeffs[5:]):
                model = "rational_polynomial"
                coeffs = (*coeffs, 0.0, 0.0, 0.0)[:8]
            else:
                coeffs = coeffs[:5]
        intrinsics = CameraIntrinsics.from_matrix(K, int(msg.width), int(msg.height))
        return CameraModel(intrinsics, model, coeffs)
    except ValueError as error:
        raise ScanFormatError(f"{where}: {error}") from None


# ---------------------------------------------------------------------- the source
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
        return self.undistorter.intrinsics

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
        self.undistorter = Undistorter(self.camera)
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
        self._mask_stamps_index = _StampIndex(self._mask_stamps)
        self._flow_stamps_index = _StampIndex(flow_stamps)
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
        masks: dict[int, np.ndarray] = {}
        flows: dict[int, np.ndarray] = {}
        # images waiting for their mask and flow picture (bag indices, -1: none needed)
        pending: deque[tuple[LoadedFrame, int, int]] = deque()
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
                    masks[mask_count] = self._decode(msg, connection.msgtype, where, mask=True)
                    mask_count += 1
                elif connection.topic == cfg.flow_topic and load_flow:
                    where = f"topic {cfg.flow_topic!r} message {flow_count}"
                    flows[flow_count] = self._decode_flow(msg, connection.msgtype, where)
                    flow_count += 1
                else:
                    where = f"topic {cfg.image_topic!r} message {index}"
                    frame = LoadedFrame(index, t_ns * 1e-9, where)
                    if last_ns is not None and t_ns < last_ns:
                        raise ScanFormatError(
                            f"{self.path}: {where}: stamp {t_ns * 1e-9:.6f} s is before the "
                            f"previous image's {last_ns * 1e-9:.6f} s: times must increase"
                        )
                    needed = flow_needed = -1
                    if last_ns is not None and t_ns == last_ns:
                        frame.skip("duplicate image stamp", "duplicate image stamp")
                    else:
                        T, reason = self.pose_at(t_ns)
                        if T is None:
                            frame.skip("no pose", f"no pose: {reason}")
                        else:
                            frame.T_world_camera = T
                            frame.rgb = self._decode(msg, connection.msgtype, where)
                            if load_masks:
                                found = self._mask_index(t_ns)
                                if found is None:
                                    frame.skip(
                                        "no mask",
                                        f"no mask on {cfg.mask_topic!r} within "
                                        f"{cfg.mask_tolerance_s:g} s",
                                    )
                                else:
                                    needed = found
                            if load_flow and frame.skip_reason is None:
                                picture = self._flow_index(t_ns)
                                flow_needed = -1 if picture is None else picture
                    last_ns = t_ns
                    index += 1
                    pending.append((frame, needed, flow_needed))
                while pending and _arrived(pending[0], masks, flows):
                    frame, needed, flow_needed = pending.popleft()
                    if needed >= 0:
                        frame.mask = masks[needed]
                    if flow_needed >= 0:
                        frame.flow_image = flows[flow_needed]
                    yield frame
                    # drop what no waiting image needs (stamps increase)
                    _drop_used(masks, needed, {n for _, n, _ in pending})
                    _drop_used(flows, flow_needed, {n for _, _, n in pending})
            for frame, needed, flow_needed in pending:  # masks or pictures that never arrived
                if needed >= 0 and needed not in masks:
                    reason = f"mask {needed} on {cfg.mask_topic!r} missing from the bag"
                    yield frame.skip("no mask", reason)
                    continue
                if needed >= 0:
                    frame.mask = masks[needed]
                frame.flow_image = flows.get(flow_needed)
                yield frame

    def _decode_flow(self, msg, msgtype: str, where: str) -> np.ndarray:
        """(H, W, 3) uint8 RGB flow picture of a message, resized and undistorted."""
        try:
            image = decode_image(msg, msgtype)
        except ValueError as error:
            raise ScanFormatError(f"{self.path}: {where}: {error}") from None
        if image.ndim != 3 or image.dtype != np.uint8:
            raise ScanFormatError(
                f"{self.path}: {where}: a flow picture must be an 8-bit colour image, got "
                f"{image.dtype} {image.shape}"
            )
        k = self.camera.intrinsics
        return flow_picture_from_array(image, k.width, k.height, self.undistorter)

    def _decode(self, msg, msgtype: str, where: str, mask: bool = False) -> np.ndarray:
        k = self.camera.intrinsics
        try:
            image = decode_image(msg, msgtype)
        except ValueError as error:
            raise ScanFormatError(f"{self.path}: {where}: {error}") from None
        if image.shape[:2] != (k.height, k.width):
            raise ScanFormatError(
                f"{self.path}: {where}: image is {image.shape[1]}x{image.shape[0]} but "
                f"{self.config.camera_info_topic!r} says {k.width}x{k.height}"
            )
        if mask:
            if image.dtype == np.uint16:
                image = (image > 0).astype(np.uint8)
            return self.undistorter.mask(mask_from_array(image, self.format_config.mask_threshold))
        if image.ndim == 2:
            image = cv2.cvtColor(image.astype(np.uint8), cv2.COLOR_GRAY2RGB)
        return self.undistorter.image(image)


class _StampIndex:
    """Stamps of a topic's messages (bag order), searchable by time.

    Args:
        stamps_ns: The messages' stamps (ns), in bag order.
    """

    def __init__(self, stamps_ns: list[int]) -> None:
        order = np.argsort(stamps_ns, kind="stable")
        self._sorted = np.asarray(stamps_ns, np.int64)[order]
        self._order = order

    def nearest(self, t_ns: int, tolerance_s: float) -> int | None:
        """Bag index of the message stamped nearest ``t_ns`` within ``tolerance_s``, or None."""
        stamps = self._sorted
        if len(stamps) == 0:
            return None
        i = int(np.searchsorted(stamps, t_ns))
        best = min(
            (j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - t_ns)
        )
        if abs(int(stamps[best]) - t_ns) > round(tolerance_s * 1e9):
            return None
        return int(self._order[best])


def _arrived(entry: tuple[LoadedFrame, int, int], masks: dict, flows: dict) -> bool:
    """Whether a waiting image's mask and flow picture (bag indices, -1: none) have been read."""
    _, mask, flow = entry
    return (mask < 0 or mask in masks) and (flow < 0 or flow in flows)


def _drop_used(decoded: dict[int, np.ndarray], used: int, still_needed: set[int]) -> None:
    """Forget the decoded messages up to ``used`` that no waiting image needs."""
    if used < 0:
        return
    for m in [m for m in decoded if m <= used and m not in still_needed]:
        del decoded[m]


class _Closing:
    """Context manager closing a rosbags reader."""

    def __init__(self, reader) -> None:
        self.reader = reader

    def __enter__(self):
        return self.reader

    def __exit__(self, *exc) -> None:
        self.reader.close()


# ---------------------------------------------------------------------- CLI helpers
def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--image-topic`` ... ``--mask-topic`` (the :class:`BagConfig` fields) to a parser."""
    group = parser.add_argument_group("ROS bag sources")
    defaults = BagConfig()
    for f in fields(BagConfig):
        flag = "--" + f.name.replace("_", "-")
        default = getattr(defaults, f.name)
        kind = float if isinstance(default, float) else str
        group.add_argument(flag, type=kind, default=default, help=f"(default: {default})")


def bag_config_from_args(args: argparse.Namespace) -> BagConfig:
    """The :class:`BagConfig` of parsed :func:`add_bag_arguments` flags ("none" -> None)."""
    values = {}
    for f in fields(BagConfig):
        value = getattr(args, f.name)
        if isinstance(value, str) and value.lower() == "none" and f.name.endswith("_topic"):
            value = None
        values[f.name] = value
    return BagConfig(**values)
