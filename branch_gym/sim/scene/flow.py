"""Ground-truth optical flow between two frames of a scan, from depth and the two camera poses.

A pixel of the first frame is lifted to 3D with its rendered depth, moved into the second
camera and projected: the flow is where it lands minus where it was. Pixels at infinity (sky,
depth inf) move by the rotation alone. The scene is static, so this is the exact flow of every
surface point that stays in view (occlusion in the second frame is not checked: a point hidden
there still gets the image position it would have).
"""

from __future__ import annotations

import numpy as np

from branch_gym.sim.scene.camera_spec import CameraSpec, check_pose, pixel_grid

__all__ = ["ground_truth_flow"]


def ground_truth_flow(
    depth_m: np.ndarray,
    T_world_camera_1: np.ndarray,
    T_world_camera_2: np.ndarray,
    spec: CameraSpec,
) -> np.ndarray:
    """Forward flow from frame 1 to frame 2.

    Args:
        depth_m: (H, W) z-depth of frame 1 in metres (inf where nothing was hit).
        T_world_camera_1: (4, 4) pose of frame 1.
        T_world_camera_2: (4, 4) pose of frame 2.
        spec: Intrinsics of both frames.

    Returns:
        (H, W, 2) float32 flow (du, dv) in pixels; NaN where the point is behind camera 2.

    Raises:
        ValueError: a depth image of another size than ``spec``, or a malformed pose.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.shape != (spec.height, spec.width):
        raise ValueError(
            f"depth_m must have shape {(spec.height, spec.width)}, got {depth_m.shape}"
        )
    T_2_1 = np.linalg.inv(check_pose(T_world_camera_2)) @ check_pose(T_world_camera_1)
    u, v = pixel_grid(spec)
    u = np.broadcast_to(u, depth_m.shape).astype(np.float64)
    v = np.broadcast_to(v, depth_m.shape).astype(np.float64)
    rays = np.stack([(u - spec.cx) / spec.fx, (v - spec.cy) / spec.fy, np.ones_like(u)], -1)
    finite = np.isfinite(depth_m)
    points = rays @ T_2_1[:3, :3].T  # rotation part: a point at infinity moves by this alone
    points[finite] += T_2_1[:3, 3] / depth_m[finite, None].astype(np.float64)
    # points = R ray + t / z: the second-camera point divided by the first depth (same projection).
    z = points[..., 2]
    flow = np.full((*depth_m.shape, 2), np.nan, dtype=np.float32)
    ahead = z > 0
    flow[ahead, 0] = spec.fx * points[ahead, 0] / z[ahead] + spec.cx - u[ahead]
    flow[ahead, 1] = spec.fy * points[ahead, 1] / z[ahead] + spec.cy - v[ahead]
    return flow
