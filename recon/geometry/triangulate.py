"""Linear multi-view triangulation of tracked pixels (paper section IV-C, eq. 1).

For a point ``j`` seen at pixels ``(u_ji, v_ji)`` by cameras with projection matrices ``P_i``
(rows ``p_i^1, p_i^2, p_i^3``), each view contributes the two rows ``u p^3 - p^1`` and
``v p^3 - p^2`` to a (2M, 4) matrix ``D_j``; the homogeneous point is the right singular vector of
``D_j`` with the smallest singular value, i.e. the eigenvector of ``D_j^T D_j`` with the smallest
eigenvalue. All points are solved at once with one batched 4x4 eigendecomposition (no Python loop
over points).

A NaN pixel marks a view in which the track was lost: its two rows are zeroed for that point only,
so every other view keeps its own projection matrix (the authors' code dropped such rows and
misaligned the remaining tracks with the poses, reference.md "Known bugs").

Conditioning: each view is moved to normalised camera coordinates (``K^-1``, recovered from its
projection matrix: image coordinates become ~0.5 and each row's algebraic error is the image error
times the point's depth) and the world origin is moved to the mean camera centre before building
``D``.
"""

from __future__ import annotations

import numpy as np

# Fewest views that determine a point.
MIN_VIEWS = 2
# |w| / ||X|| below this: the homogeneous solution is a point at infinity (degenerate geometry).
_MIN_HOMOGENEOUS_SCALE = 1e-12
# Second-smallest over largest eigenvalue of D^T D below this: the null space is 2-D (no baseline,
# e.g. every view from one optical centre) and the point is not determined. Real baselines give
# ~1e-3 (8 views 1 mm apart at 0.2 m); 1e-14 only catches exact degeneracy.
_MIN_EIGENVALUE_RATIO = 1e-14


def triangulate_points(
    pixels: np.ndarray, projections: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate tracked pixels by the linear DLT / SVD method of paper eq. (1).

    Args:
        pixels: (M, N, 2) pixel coordinates (u, v) of N points in M views; NaN (or any non-finite
            coordinate) marks a view where that point's track is not valid.
        projections: (M, 3, 4) world-to-image projection matrices ``K [R | t]``
            (:func:`recon.camera.projection_matrix`), one per view.

    Returns:
        points: (N, 3) points in metres, world frame; NaN where fewer than two views are valid or
            the geometry is degenerate (no baseline between the valid views, or a solution at
            infinity).
        max_reprojection_px: (N,) largest reprojection error in pixels over the valid views of each
            point; ``inf`` where the point is NaN or lies behind a camera that observed it.

    Raises:
        ValueError: wrong shapes, fewer than two views, or non-finite projection matrices.
    """
    pixels, projections = _check_inputs(pixels, projections)
    n_views, n_points = pixels.shape[:2]
    points = np.full((n_points, 3), np.nan)
    max_error_px = np.full(n_points, np.inf)
    if n_points == 0:
        return points, max_error_px

    valid = np.all(np.isfinite(pixels), axis=2)  # (M, N)
    enough_views = valid.sum(axis=0) >= MIN_VIEWS
    safe_pixels = np.where(valid[..., None], pixels, 0.0)

    norm_pixels, norm_projections = _normalise_by_intrinsics(safe_pixels, projections)
    origin = _mean_camera_centre(projections)
    shift = np.eye(4)
    shift[:3, 3] = origin
    shifted = norm_projections @ shift  # (M, 3, 4): acts on X - origin

    # Rows of D_j (paper eq. 1): u p3 - p1 and v p3 - p2, zeroed where the view is not valid.
    rows = norm_pixels[..., None] * shifted[:, None, 2:3, :] - shifted[:, None, 0:2, :]
    rows *= valid[..., None, None]  # (M, N, 2, 4)
    design = rows.transpose(1, 0, 2, 3).reshape(n_points, 2 * n_views, 4)

    # The right singular vector of D_j for its smallest singular value is the eigenvector of the
    # 4x4 Gram matrix D_j^T D_j for its smallest eigenvalue: same solution, ~3x cheaper batched.
    gram = design.transpose(0, 2, 1) @ design  # (N, 4, 4)
    eigenvalues, eigenvectors = np.linalg.eigh(gram)  # ascending eigenvalues
    homogeneous = eigenvectors[:, :, 0]  # (N, 4)
    determined = eigenvalues[:, 1] > _MIN_EIGENVALUE_RATIO * eigenvalues[:, 3]
    scale = homogeneous[:, 3]
    finite = np.abs(scale) > _MIN_HOMOGENEOUS_SCALE * np.linalg.norm(homogeneous, axis=1)
    solved = enough_views & determined & finite
    points[solved] = homogeneous[solved, :3] / scale[solved, None] + origin

    max_error_px[solved] = _max_reprojection_error(
        points[solved], pixels[:, solved], valid[:, solved], projections
    )
    return points, max_error_px


def _check_inputs(pixels: np.ndarray, projections: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate shapes and return float arrays."""
    pixels = np.asarray(pixels, dtype=float)
    projections = np.asarray(projections, dtype=float)
    if pixels.ndim != 3 or pixels.shape[2] != 2:
        raise ValueError(f"pixels must have shape (M, N, 2), got {pixels.shape}")
    if projections.ndim != 3 or projections.shape[1:] != (3, 4):
        raise ValueError(f"projections must have shape (M, 3, 4), got {projections.shape}")
    if pixels.shape[0] != projections.shape[0]:
        raise ValueError(
            f"pixels hold {pixels.shape[0]} views but projections hold {projections.shape[0]}"
        )
    if pixels.shape[0] < MIN_VIEWS:
        raise ValueError(f"triangulation needs at least {MIN_VIEWS} views, got {pixels.shape[0]}")
    if not np.all(np.isfinite(projections)):
        raise ValueError("projections contain NaN or infinite values")
    return pixels, projections


def _normalise_by_intrinsics(
    pixels: np.ndarray, projections: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Move every view to normalised camera coordinates: ``K_i^-1 x`` and ``K_i^-1 P_i``.

    ``K_i`` is recovered from ``P_i`` alone (``M M^T = K K^T`` for ``M = K R``, an upper Cholesky
    factor), so the transform does not depend on which points are tracked: triangulating a subset
    of points or views gives exactly the same result.

    Args:
        pixels: (M, N, 2) pixels, finite everywhere (invalid entries hold any finite value).
        projections: (M, 3, 4) projection matrices.

    Returns:
        (M, N, 2) normalised image coordinates and (M, 3, 4) normalised projection matrices.

    Raises:
        ValueError: a projection matrix whose 3x3 block is singular.
    """
    left = projections[:, :, :3]
    flip = np.eye(3)[::-1]  # exchange matrix J: J A J turns upper into lower triangular
    try:
        lower = np.linalg.cholesky(flip @ left @ left.transpose(0, 2, 1) @ flip)
    except np.linalg.LinAlgError as error:
        raise ValueError("a projection matrix has a singular 3x3 block") from error
    k_inverse = np.linalg.inv(flip @ lower @ flip)  # (M, 3, 3), upper triangular
    homogeneous = np.concatenate([pixels, np.ones((*pixels.shape[:2], 1))], axis=2)
    normalised = homogeneous @ k_inverse.transpose(0, 2, 1)  # (M, N, 3)
    return normalised[..., :2] / normalised[..., 2:3], k_inverse @ projections


def _mean_camera_centre(projections: np.ndarray) -> np.ndarray:
    """(3,) mean optical centre of the cameras, metres, world frame (``P C = 0``)."""
    left, right = projections[:, :, :3], projections[:, :, 3]
    try:
        centres = -np.linalg.solve(left, right[..., None])[..., 0]
    except np.linalg.LinAlgError as error:
        raise ValueError("a projection matrix has a singular 3x3 block") from error
    return centres.mean(axis=0)


def _max_reprojection_error(
    points: np.ndarray, pixels: np.ndarray, valid: np.ndarray, projections: np.ndarray
) -> np.ndarray:
    """Largest reprojection error over the valid views of each point.

    Args:
        points: (K, 3) points in metres, world frame.
        pixels: (M, K, 2) observed pixels.
        valid: (M, K) which observations count.
        projections: (M, 3, 4) projection matrices.

    Returns:
        (K,) maximum error in pixels; ``inf`` where the point is behind an observing camera.
    """
    homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
    projected = homogeneous @ projections.transpose(0, 2, 1)  # (M, K, 3)
    depth = projected[..., 2]
    in_front = depth > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        error = np.linalg.norm(projected[..., :2] / depth[..., None] - pixels, axis=2)
    error = np.where(valid, error, 0.0)
    error = np.where(valid & ~in_front, np.inf, error)
    return error.max(axis=0)
