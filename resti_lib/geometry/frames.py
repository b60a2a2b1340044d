"""Rigid transforms, rotation checks, quaternions and axis conventions.

Conventions (see ``docs/design.md``)
------------------------------------
- A rigid transform is a 4x4 float64 array ``T_a_from_b``; it maps homogeneous points of frame
  ``b`` to frame ``a``: ``p_a = T_a_from_b @ p_b``. Batches have shape ``[..., 4, 4]``.
- Rotations are 3x3 matrices acting on column vectors; ``R_a_from_b`` maps directions of ``b`` to ``a``.
- Quaternions in source files are scalar-first ``(w, x, y, z)``; SciPy's ``Rotation.from_quat`` is
  scalar-last, so the conversion below reorders explicitly.
- Camera axes in every output are OpenCV (+X right, +Y down, +Z optical forward). Waymo camera and
  vehicle frames are +X forward, +Y left, +Z up, related by
  ``x_cv = -y_w, y_cv = -z_w, z_cv = x_w``.
- Angles are radians unless a name says ``deg``.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from resti_lib.errors import InputError

__all__ = [
    "R_CV_FROM_WAYMO",
    "R_WAYMO_FROM_CV",
    "T_CV_CAM_FROM_WAYMO_CAM",
    "T_WAYMO_CAM_FROM_CV_CAM",
    "apply_T",
    "check_rotation",
    "invert_T",
    "make_T",
    "matrix_to_quat_wxyz",
    "nearest_rotation",
    "opencv_cam_pose_to_waymo",
    "opencv_to_waymo_points",
    "quat_wxyz_to_matrix",
    "rotation_angle_deg",
    "waymo_cam_pose_to_opencv",
    "waymo_to_opencv_points",
    "yaw_matrix",
]

#: Rotation taking Waymo camera-axis coordinates to OpenCV camera-axis coordinates:
#: ``p_cv = R_CV_FROM_WAYMO @ p_w`` with ``x_cv = -y_w, y_cv = -z_w, z_cv = x_w``.
R_CV_FROM_WAYMO = np.array([[0.0, -1.0, 0.0],
                            [0.0, 0.0, -1.0],
                            [1.0, 0.0, 0.0]])
#: Inverse (= transpose) of :data:`R_CV_FROM_WAYMO`: ``p_w = R_WAYMO_FROM_CV @ p_cv``.
R_WAYMO_FROM_CV = R_CV_FROM_WAYMO.T.copy()


def make_T(R: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """Build rigid transform(s) from rotation(s) and translation(s).

    Parameters
    ----------
    R : array, shape ``[..., 3, 3]``
        Rotation ``R_a_from_b``.
    t : array, shape ``[..., 3]``, optional
        Translation: the origin of ``b`` expressed in ``a`` (default zero).

    Returns
    -------
    T : float64 array, shape ``[..., 4, 4]``, ``T_a_from_b``.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"rotation must have shape [..., 3, 3], got {R.shape}")
    batch = R.shape[:-2]
    if t is None:
        t = np.zeros(batch + (3,))
    t = np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(batch, t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


#: ``T_waymo_cam_from_cv_cam``: right-multiply a Waymo-axes camera pose to get OpenCV axes.
T_WAYMO_CAM_FROM_CV_CAM = make_T(R_WAYMO_FROM_CV)
#: ``T_cv_cam_from_waymo_cam``: the inverse of :data:`T_WAYMO_CAM_FROM_CV_CAM`.
T_CV_CAM_FROM_WAYMO_CAM = make_T(R_CV_FROM_WAYMO)


def invert_T(T: np.ndarray) -> np.ndarray:
    """Invert rigid transform(s) in closed form: ``(R, t) -> (R^T, -R^T t)``.

    Parameters
    ----------
    T : array, shape ``[..., 4, 4]``, ``T_a_from_b`` (the last row is assumed ``[0, 0, 0, 1]``).

    Returns
    -------
    float64 array, shape ``[..., 4, 4]``: ``T_b_from_a``.
    """
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    t = T[..., :3, 3]
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def apply_T(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply rigid transform(s) to 3D points.

    Parameters
    ----------
    T : array, shape ``[4, 4]`` or ``[..., 4, 4]`` (``T_a_from_b``).
    pts : array, shape ``[..., 3]``, points in frame ``b``.

    Returns
    -------
    float64 array, shape ``[..., 3]``: the points in frame ``a``. A single ``T`` applies to every
    point; a batch of ``T`` broadcasts against the batch of points.
    """
    T = np.asarray(T, dtype=np.float64)
    pts = np.asarray(pts, dtype=np.float64)
    if T.ndim == 2:
        return pts @ T[:3, :3].T + T[:3, 3]
    return np.einsum("...ij,...j->...i", T[..., :3, :3], pts) + T[..., :3, 3]


def check_rotation(R: np.ndarray, *, tol: float = 1e-6, file: str | Path | None = None,
                   row: object = None, field: str | None = None) -> np.ndarray:
    """Check that ``R`` is a proper rotation; return it as float64.

    Parameters
    ----------
    R : array, shape ``[3, 3]`` or ``[N, 3, 3]``.
    tol : float
        Largest allowed absolute entry of ``R R^T - I`` (float32 sources need about ``1e-5``).
    file, row, field :
        Where ``R`` came from, for the error message. For a batch with ``row=None`` the index of
        the first failing matrix is reported as the row.

    Raises
    ------
    InputError
        When any entry is non-finite, ``|R R^T - I| > tol`` or ``det(R) < 0``.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise InputError(f"rotation must be 3x3, got shape {R.shape}", file=file, row=row, field=field)
    batch = R.reshape(-1, 3, 3)

    def where(i: int) -> object:
        return row if (row is not None or R.ndim == 2) else i

    finite = np.isfinite(batch).all(axis=(1, 2))
    if not finite.all():
        i = int(np.argmin(finite))
        raise InputError("rotation has non-finite entries", file=file, row=where(i), field=field)
    err = np.abs(batch @ np.swapaxes(batch, 1, 2) - np.eye(3)).max(axis=(1, 2))
    if (err > tol).any():
        i = int(np.argmax(err))
        raise InputError(f"rotation is not orthonormal: max |R R^T - I| = {err[i]:.3g} > {tol:g}",
                         file=file, row=where(i), field=field)
    det = np.linalg.det(batch)
    if (det < 0).any():
        i = int(np.argmin(det))
        raise InputError(f"rotation has det {det[i]:.6f} < 0 (a reflection)",
                         file=file, row=where(i), field=field)
    return R


def quat_wxyz_to_matrix(q: np.ndarray, *, file: str | Path | None = None, row: object = None,
                        field: str | None = None, norm_tol: float = 1e-12) -> np.ndarray:
    """Rotation matrix from scalar-first quaternion(s) ``(w, x, y, z)``.

    The quaternion is normalised first (so ``q`` and ``-q`` give the same matrix); the result is
    ``R`` such that ``v' = R v`` rotates by ``q`` (Hamilton convention, as SciPy).

    Parameters
    ----------
    q : array, shape ``[4]`` or ``[N, 4]``, scalar first.

    Returns
    -------
    float64 array, shape ``[3, 3]`` or ``[N, 3, 3]``.

    Raises
    ------
    InputError
        Wrong shape, non-finite entries or (near-)zero norm.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,) or q.ndim > 2:
        raise InputError(f"quaternion must have shape [4] or [N, 4], got {q.shape}",
                         file=file, row=row, field=field)
    batch = q.reshape(-1, 4)
    bad = ~np.isfinite(batch).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError("quaternion has non-finite entries", file=file,
                         row=row if row is not None or q.ndim == 1 else i, field=field)
    norm = np.linalg.norm(batch, axis=1)
    if (norm <= norm_tol).any():
        i = int(np.argmin(norm))
        raise InputError("quaternion has zero norm", file=file,
                         row=row if row is not None or q.ndim == 1 else i, field=field)
    # SciPy expects scalar-last (x, y, z, w): move w to the end explicitly.
    xyzw = np.concatenate([batch[:, 1:], batch[:, :1]], axis=1) / norm[:, None]
    R = Rotation.from_quat(xyzw).as_matrix()
    return R[0] if q.ndim == 1 else R


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternion(s) ``(w, x, y, z)`` with ``w >= 0`` from rotation matrices."""
    R = np.asarray(R, dtype=np.float64)
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    wxyz = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    wxyz *= np.where(wxyz[:, :1] < 0, -1.0, 1.0)
    return wxyz[0] if R.ndim == 2 else wxyz.reshape(R.shape[:-2] + (4,))


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation matrix nearest (Frobenius) to ``R``: ``U V^T`` of its SVD, the sign fixed so that
    the determinant is +1. A printed matrix rounded to two decimals is not orthonormal."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt


def rotation_angle_deg(R0: np.ndarray, R1: np.ndarray) -> float:
    """Angle of the relative rotation ``R0^T R1`` in degrees, both first projected onto SO(3)
    (:func:`nearest_rotation`): two matrices that agree to rounding give about 0 degrees, not the
    arccos of a trace pushed off 3 by non-orthonormal entries. The angle is ``atan2`` of the
    rotation's sine and cosine, accurate near 0 and 180 degrees alike."""
    M = _nearest_printed(R0).T @ _nearest_printed(R1)
    sin = 0.5 * math.hypot(M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1])
    cos = 0.5 * (M[0, 0] + M[1, 1] + M[2, 2] - 1.0)
    return math.degrees(math.atan2(sin, cos))


def _nearest_printed(R) -> np.ndarray:
    # candidates meet in every pair of a row, so each printed matrix is projected once
    return _nearest_of(tuple(np.asarray(R, dtype=np.float64).ravel().tolist()))


@lru_cache(maxsize=4096)
def _nearest_of(flat: tuple) -> np.ndarray:
    out = nearest_rotation(np.array(flat, dtype=np.float64).reshape(3, 3))
    out.flags.writeable = False
    return out


def yaw_matrix(theta: float | np.ndarray) -> np.ndarray:
    """Rotation(s) by ``theta`` radians about +Z (counter-clockwise seen from +Z).

    ``yaw_matrix(theta) @ [1, 0, 0] = [cos theta, sin theta, 0]``; shape ``[3, 3]`` or ``[..., 3, 3]``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R


def waymo_cam_pose_to_opencv(T_world_from_waymo_cam: np.ndarray) -> np.ndarray:
    """``T_world<-cam`` in OpenCV camera axes from a pose whose camera axes are Waymo's.

    ``T_world_from_cv = T_world_from_waymo @ T_WAYMO_CAM_FROM_CV_CAM``; works on ``[..., 4, 4]``.
    """
    return np.asarray(T_world_from_waymo_cam, dtype=np.float64) @ T_WAYMO_CAM_FROM_CV_CAM


def opencv_cam_pose_to_waymo(T_world_from_cv_cam: np.ndarray) -> np.ndarray:
    """Inverse of :func:`waymo_cam_pose_to_opencv` (OpenCV camera axes -> Waymo camera axes)."""
    return np.asarray(T_world_from_cv_cam, dtype=np.float64) @ T_CV_CAM_FROM_WAYMO_CAM


def waymo_to_opencv_points(p_waymo: np.ndarray) -> np.ndarray:
    """Camera-frame points ``[..., 3]`` from Waymo axes to OpenCV axes (``x_cv = -y_w`` ...)."""
    return np.asarray(p_waymo, dtype=np.float64) @ R_CV_FROM_WAYMO.T


def opencv_to_waymo_points(p_cv: np.ndarray) -> np.ndarray:
    """Camera-frame points ``[..., 3]`` from OpenCV axes to Waymo axes."""
    return np.asarray(p_cv, dtype=np.float64) @ R_WAYMO_FROM_CV.T
