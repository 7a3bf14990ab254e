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

The package, by concern: ``config.py`` (:class:`BagConfig` and its command-line flags),
``source.py`` (:class:`BagSource`: opening a bag, its frames), ``transforms.py`` (TF chains and
their interpolation), ``decoding.py`` (stamps, images, calibration) and ``sync.py`` (masks and flow
pictures matched to images by stamp).
"""

from recon.io.rosbag.config import BagConfig, add_bag_arguments, bag_config_from_args
from recon.io.rosbag.decoding import FrameDecoder, camera_from_info, decode_image, stamp_ns
from recon.io.rosbag.source import (
    BAG_SUFFIXES,
    CAMERA_INFO_TYPE,
    IMAGE_TYPES,
    POSE_TYPE,
    TF_TYPE,
    BagSource,
    is_bag,
    require_rosbags,
)
from recon.io.rosbag.sync import PendingFrames, StampIndex
from recon.io.rosbag.transforms import (
    TransformSeries,
    TransformTree,
    pose_matrix,
    quaternion_slerp,
)

__all__ = [
    "BAG_SUFFIXES",
    "CAMERA_INFO_TYPE",
    "IMAGE_TYPES",
    "POSE_TYPE",
    "TF_TYPE",
    "BagConfig",
    "BagSource",
    "FrameDecoder",
    "PendingFrames",
    "StampIndex",
    "TransformSeries",
    "TransformTree",
    "add_bag_arguments",
    "bag_config_from_args",
    "camera_from_info",
    "decode_image",
    "is_bag",
    "pose_matrix",
    "quaternion_slerp",
    "require_rosbags",
    "stamp_ns",
]
