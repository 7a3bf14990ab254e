"""Rotation-minimising frames along a curve: the normals of a swept tube that does not twist.

The one implementation of the tube frames: the simulator's tree meshes
(``branch_gym/sim/scene/tube_rings.py``) and the PLY meshes of reconstructed models
(:mod:`recon.io.mesh`) both sweep their rings with it.

>>> import numpy as np
>>> centres = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 2.0]])
>>> tangents = np.array([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8], [0.0, 1.0, 0.0]])
>>> normals = rotation_minimising_frames(centres, tangents)
>>> bool(np.allclose(np.einsum("ij,ij->i", normals, tangents), 0.0))  # perpendicular
True
>>> bool(np.allclose(np.linalg.norm(normals, axis=1), 1.0))  # unit length
True
"""

from __future__ import annotations

import numpy as np

_SAME_TANGENT_SQUARED = 1e-18  # |t1 - reflected t0|^2 below this: no second reflection needed


def rotation_minimising_frames(centres: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Reference normals along a curve by the double-reflection method (Wang et al. 2008).

    Args:
        centres: (R, 3) points on the curve in metres, consecutive points distinct.
        tangents: (R, 3) unit tangents at those points.

    Returns:
        (R, 3) unit normals perpendicular to the tangents, turning as little as possible; the third
        axis of each right-handed frame is ``cross(tangent, normal)``.
    """
    helper = np.eye(3)[int(np.argmin(np.abs(tangents[0])))]
    normals = np.empty_like(centres)
    normals[0] = np.cross(tangents[0], helper)
    normals[0] /= np.linalg.norm(normals[0])
    for i in range(len(centres) - 1):
        v1 = centres[i + 1] - centres[i]
        c1 = float(v1 @ v1)
        reflected_normal = normals[i] - (2.0 / c1) * float(v1 @ normals[i]) * v1
        reflected_tangent = tangents[i] - (2.0 / c1) * float(v1 @ tangents[i]) * v1
        v2 = tangents[i + 1] - reflected_tangent
        c2 = float(v2 @ v2)
        n = (
            reflected_normal - (2.0 / c2) * float(v2 @ reflected_normal) * v2
            if c2 > _SAME_TANGENT_SQUARED
            else reflected_normal
        )
        n = n - float(n @ tangents[i + 1]) * tangents[i + 1]  # remove round-off drift
        normals[i + 1] = n / np.linalg.norm(n)
    return normals
