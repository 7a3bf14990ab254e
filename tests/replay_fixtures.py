"""Shared helpers of the replay tests: a short recorded simulated scan and a ROS 2 bag writer."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from recon.camera import invert_pose, make_pose
from recon.io import ScanFolder

# A short scan: 0.275 m -> 0.34 m, ~50 frames, 6 iterations, one secondary on tree 0 (~2 s).
SHORT_END_HEIGHT_M = 0.34
BAG_START_NS = 1_700_000_000_000_000_000
# Static mount of the optical frame on the flange (a rotation and an offset, as on a real arm).
T_TOOL_OPTICAL = make_pose(Rotation.from_euler("xyz", [3.0, -2.0, 91.0], degrees=True).as_matrix(),
                           [0.01, -0.02, 0.05])  # fmt: skip


def record_short_scan(out: Path, seed: int = 0, **kwargs) -> object:
    """Record the short scan of tree ``seed`` into ``out``; returns the ScanResult."""
    from agents.factory import AGENTS
    from branch_gym.evaluation.record import record_scan
    from branch_gym.scan import ScanConfig

    scan = ScanConfig(end_height_m=SHORT_END_HEIGHT_M)
    return record_scan(seed, "none", scan, out, factory=AGENTS, **kwargs)


def _stamp(ts, t_ns: int):
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def _header(ts, t_ns: int, frame_id: str):
    return ts.types["std_msgs/msg/Header"](stamp=_stamp(ts, t_ns), frame_id=frame_id)


def image_msg(ts, image: np.ndarray, t_ns: int, encoding: str, frame_id: str = "camera"):
    """sensor_msgs/Image of an (H, W, 3) RGB or (H, W) uint8 array in ``encoding``."""
    if encoding == "bgr8":
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    image = np.ascontiguousarray(image)
    h, w = image.shape[:2]
    step = image.strides[0]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, t_ns, frame_id),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=image.reshape(-1).view(np.uint8),
    )


def compressed_msg(ts, image: np.ndarray, t_ns: int, fmt: str = "png"):
    """sensor_msgs/CompressedImage (lossless PNG by default) of an RGB or grey image."""
    data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode("." + fmt, data)
    assert ok
    return ts.types["sensor_msgs/msg/CompressedImage"](
        header=_header(ts, t_ns, "camera"), format=fmt, data=buf.reshape(-1)
    )


def camera_info_msg(ts, k, t_ns: int, model: str = "plumb_bob", d=(0.0,) * 5):
    """sensor_msgs/CameraInfo of recon intrinsics ``k``."""
    K = k.K.reshape(-1)
    P = np.hstack([k.K, np.zeros((3, 1))]).reshape(-1)
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, t_ns, "camera_color_optical_frame"),
        height=k.height,
        width=k.width,
        distortion_model=model,
        d=np.asarray(d, float),
        k=K,
        r=np.eye(3).reshape(-1),
        p=P,
        binning_x=0,
        binning_y=0,
        roi=ts.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def transform_stamped(ts, T: np.ndarray, t_ns: int, parent: str, child: str):
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    g = ts.types
    return g["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, t_ns, parent),
        child_frame_id=child,
        transform=g["geometry_msgs/msg/Transform"](
            translation=g["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=g["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )


def pose_stamped(ts, T: np.ndarray, t_ns: int, frame: str = "base_link"):
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    g = ts.types
    return g["geometry_msgs/msg/PoseStamped"](
        header=_header(ts, t_ns, frame),
        pose=g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            orientation=g["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )


def write_bag(
    scan_dir: Path,
    bag: Path,
    storage: str = "sqlite3",
    compressed: bool = False,
    tf_until_frame: int | None = None,
    pose_topic: bool = False,
    image_topic: str = "/camera/color/image_raw",
    mask_topic: str | None = "/image_mask",
    stamp_offsets_ns: dict[int, int] | None = None,
    info_intrinsics=None,
    n_frames: int | None = None,
    flow_topic: str | None = None,
) -> list[int]:
    """Write a recorded scan folder as a ROS 2 bag, as the authors record them.

    Topics: images (rgb8 Image, or PNG CompressedImage), ``/camera/color/camera_info`` with
    every image, ``/tf`` (``base_link -> tool0`` at every image time), ``/tf_static``
    (``tool0 -> camera_color_optical_frame``), masks (mono8 0/255, published after their image,
    as a segmenter would), optionally a ``/camera_pose`` PoseStamped.

    Args:
        tf_until_frame: Stop publishing /tf after this frame (later images have no pose).
        stamp_offsets_ns: frame index -> offset added to that image's header stamp, not to its
            bag time (bad input: stamps out of order).
        info_intrinsics: CameraInfo intrinsics other than the scan's (bad input).
        n_frames: Write only the first frames (0: none, an empty image topic).
        flow_topic: Also publish the folder's flow pictures (rgb8, with their image's stamp,
            10 ms after it) on this topic.

    Returns:
        The image stamps (ns).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    scan = ScanFolder(scan_dir)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    stamps = []
    with Writer(bag, version=9, storage_plugin=plugin) as writer:
        c_image = writer.add_connection(image_topic, image_type, typestore=ts)
        c_info = writer.add_connection(
            "/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts
        )
        c_tf = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_static = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        c_mask = None
        if mask_topic is not None:
            c_mask = writer.add_connection(mask_topic, image_type, typestore=ts)
        c_flow = None
        if flow_topic is not None:
            c_flow = writer.add_connection(flow_topic, "sensor_msgs/msg/Image", typestore=ts)
        c_pose = None
        if pose_topic:
            c_pose = writer.add_connection(
                "/camera_pose", "geometry_msgs/msg/PoseStamped", typestore=ts
            )
        TF = ts.types["tf2_msgs/msg/TFMessage"]
        mount = transform_stamped(
            ts, T_TOOL_OPTICAL, BAG_START_NS, "tool0", "camera_color_optical_frame"
        )
        static = TF(transforms=[mount])
        writer.write(c_static, BAG_START_NS, ts.serialize_cdr(static, TF.__msgtype__))
        for loaded in scan.frames(load_flow=flow_topic is not None):
            if n_frames is not None and loaded.index >= n_frames:
                break
            t_ns = BAG_START_NS + round(loaded.time_s * 1e9)
            stamp = t_ns + (stamp_offsets_ns or {}).get(loaded.index, 0)  # header only
            stamps.append(stamp)
            T = loaded.T_world_camera
            if tf_until_frame is None or loaded.index <= tf_until_frame:
                T_base_tool = T @ invert_pose(T_TOOL_OPTICAL)
                tf = TF(transforms=[transform_stamped(ts, T_base_tool, t_ns, "base_link", "tool0")])
                writer.write(c_tf, t_ns, ts.serialize_cdr(tf, TF.__msgtype__))
            if c_pose is not None:
                msg = pose_stamped(ts, T, t_ns)
                writer.write(c_pose, t_ns, ts.serialize_cdr(msg, msg.__msgtype__))
            info = camera_info_msg(ts, info_intrinsics or scan.intrinsics, t_ns)
            writer.write(c_info, t_ns, ts.serialize_cdr(info, info.__msgtype__))
            if compressed:
                msg = compressed_msg(ts, loaded.rgb, stamp)
            else:
                msg = image_msg(ts, loaded.rgb, stamp, "rgb8")
            writer.write(c_image, t_ns + 1000, ts.serialize_cdr(msg, image_type))
            if c_flow is not None and loaded.flow_image is not None:
                fmsg = image_msg(ts, loaded.flow_image, stamp, "rgb8")
                writer.write(c_flow, t_ns + 10_000_000, ts.serialize_cdr(fmsg, fmsg.__msgtype__))
            if c_mask is not None:
                mask = np.where(loaded.mask, 255, 0).astype(np.uint8)
                if compressed:
                    mmsg = compressed_msg(ts, mask, t_ns)
                else:
                    mmsg = image_msg(ts, mask, t_ns, "mono8")
                # the segmenter publishes the mask 20 ms after the image, with the image's stamp
                writer.write(c_mask, t_ns + 20_000_000, ts.serialize_cdr(mmsg, image_type))
    return stamps
