"""The degeneracy-aware part of ICP (:func:`skelfuse.calibration.icp.refine_icp`, step 4): keep
only the part of a correction that the shared surfaces determine.

Where two sensors share mostly floor, point-to-plane ICP slides along it (yaw and horizontal
position) while its fitness looks fine; the correction is projected onto the well-determined
directions of the point-to-plane normal matrix and the rest keeps the initial guess.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.protocol.transform import Matrix4

FloatArray = npt.NDArray[np.float64]


def _rotvec_to_matrix(rotvec: FloatArray) -> FloatArray:
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.eye(3)
    k = rotvec / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation: FloatArray = np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
    return rotation


def _matrix_to_rotvec(rotation: FloatArray) -> FloatArray:
    angle = np.radians(rotation_angle_deg(rotation))
    if angle < 1e-12:
        return np.zeros(3)
    axis = np.array(
        [
            rotation[2, 1] - rotation[1, 2],
            rotation[0, 2] - rotation[2, 0],
            rotation[1, 0] - rotation[0, 1],
        ]
    )
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:  # angle near 180°: take the axis from R + I
        sym = rotation + np.eye(3)
        axis = sym[:, int(np.argmax(np.linalg.norm(sym, axis=0)))]
        norm = float(np.linalg.norm(axis))
    rotvec: FloatArray = axis / norm * angle
    return rotvec


def constrained_update(
    source: FloatArray,
    target: FloatArray,
    target_normals: FloatArray,
    init: Matrix4,
    result: Matrix4,
    distance: float,
    min_ratio: float,
) -> tuple[Matrix4, int]:
    """Keep only the part of the ICP correction that the shared surfaces determine.

    Builds the point-to-plane normal matrix at ``result`` (rotation about the matched source
    centroid, scaled by the cloud's RMS radius so that rotation and translation compare) and
    projects the correction ``result·init⁻¹`` onto its eigenvectors whose eigenvalue is at least
    ``min_ratio`` of the largest: directions along which the surfaces slide (e.g. yaw and
    horizontal position when only the floor is shared) keep the initial guess.

    Returns:
        the projected transform and the number of constrained directions (0..6).
    """
    from scipy.spatial import cKDTree

    moved = source @ result[:3, :3].T + result[:3, 3]
    dist, index = cKDTree(target).query(moved, distance_upper_bound=distance)
    matched = np.isfinite(dist)
    if matched.sum() < 6:
        return init.copy(), 0
    points, normals = moved[matched], target_normals[index[matched]]
    centre = points.mean(axis=0)
    centred = points - centre
    scale = max(float(np.sqrt((centred**2).sum(axis=1).mean())), 1e-6)
    jacobian = np.hstack([np.cross(centred, normals) / scale, normals])
    eigenvalues, eigenvectors = np.linalg.eigh(jacobian.T @ jacobian)
    strong = eigenvalues >= min_ratio * eigenvalues[-1]
    correction = result @ np.linalg.inv(init)  # target frame
    rot = correction[:3, :3]
    twist = np.concatenate(
        [_matrix_to_rotvec(rot) * scale, rot @ centre + correction[:3, 3] - centre]
    )
    basis = eigenvectors[:, strong]
    kept = basis @ (basis.T @ twist)
    rot_kept = _rotvec_to_matrix(kept[:3] / scale)
    update = np.eye(4)
    update[:3, :3] = rot_kept
    update[:3, 3] = centre + kept[3:] - rot_kept @ centre
    projected: Matrix4 = update @ init
    return projected, int(strong.sum())
