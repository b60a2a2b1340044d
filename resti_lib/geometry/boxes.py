"""Oriented boxes: the one box type of the package and the tight gravity-upright box of a point set.

An :class:`OrientedBox` is ``center`` and ``R = R_frame_from_box`` in some frame with box-local
edge lengths ``lwh`` along box +X, +Y, +Z.

:func:`upright_oriented_box` is the box ScanNet instances get (and Dimensional Measurement and
3D Video Grounding report): box +Z is the frame's +Z (gravity up), the footprint is the
minimum-area rectangle of the points' XY coordinates (``trimesh.bounds.oriented_bounds_2D``:
one side along a convex-hull side, so the footprint is never larger than the axis-aligned one;
hull sides parallel to it within 1e-4 rad share its direction, see :func:`_min_area_yaw`), the
height is the vertical extent. Box +X runs along the longer horizontal side
(``length >= width``) and the yaw of box +X is normalised to (-90, 90] degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resti_lib.geometry.frames import apply_T, make_T, yaw_matrix

__all__ = ["PARALLEL_SIDES_RAD", "OrientedBox", "upright_oriented_box"]


@dataclass
class OrientedBox:
    """An oriented box: ``center`` and ``R = R_frame_from_box`` in some frame, edge lengths ``lwh``.

    ``lwh = (length, width, height)`` are the box-local edge lengths along box +X, +Y, +Z.
    """

    center: np.ndarray
    R: np.ndarray
    lwh: np.ndarray

    @property
    def T(self) -> np.ndarray:
        """``T_frame_from_box`` (4x4)."""
        return make_T(self.R, self.center)

    @property
    def yaw_deg(self) -> float:
        """Heading of box +X about the frame's +Z, degrees (``atan2(R[1,0], R[0,0])``)."""
        return float(np.degrees(np.arctan2(self.R[1, 0], self.R[0, 0])))

    @property
    def footprint_area(self) -> float:
        """``length * width`` (m² for metre boxes): the area of the box's horizontal section."""
        return float(self.lwh[0] * self.lwh[1])

    def corners(self) -> np.ndarray:
        """The 8 corners ``[8, 3]`` in the box's frame of reference."""
        s = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
        return apply_T(self.T, s * self.lwh)

    def transformed(self, T_new_from_frame: np.ndarray) -> OrientedBox:
        """The same box expressed in another frame (rigid ``T_new_from_frame``)."""
        T = np.asarray(T_new_from_frame, dtype=np.float64) @ self.T
        return OrientedBox(T[:3, 3].copy(), T[:3, :3].copy(), self.lwh.copy())

    @classmethod
    def axis_aligned(cls, points: np.ndarray) -> OrientedBox:
        """The axis-aligned box of points ``[N, 3]`` in their own frame (``R = I``)."""
        P = _points(points)
        lo, hi = P.min(axis=0), P.max(axis=0)
        return cls((lo + hi) / 2, np.eye(3), hi - lo)


def _points(points: np.ndarray) -> np.ndarray:
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] == 0:
        raise ValueError(f"points must be [N>0, 3], got {P.shape}")
    return P


#: hull sides within this angle (rad, modulo 90 degrees) of the minimum-area side share its direction
PARALLEL_SIDES_RAD = 1e-4


def _min_area_yaw(xy: np.ndarray) -> float:
    """Yaw (rad) of one side of the minimum-area rectangle of 2-D points.

    ``trimesh.bounds.oriented_bounds_2D`` finds the rectangle (one side along a hull side). When
    several hull sides are parallel to that side within :data:`PARALLEL_SIDES_RAD` modulo 90
    degrees (the four sides of a box-shaped instance whose vertices carry float32 noise), the yaw is
    their length-weighted mean direction, so the box does not depend on which noisy side happened
    to give the least area. Points without a 2-D hull (all equal or collinear) take the direction
    of their spread (the rectangle is then a segment or a point).
    """
    from scipy.spatial import ConvexHull, QhullError
    from trimesh.bounds import oriented_bounds_2D

    try:
        T, _ = oriented_bounds_2D(xy)
        hull = ConvexHull(xy, qhull_options="QbB")
    except (QhullError, ValueError):
        c = xy - xy.mean(axis=0)
        if not np.any(c):
            return 0.0
        _, _, vt = np.linalg.svd(c, full_matrices=False)
        return float(np.arctan2(vt[0, 1], vt[0, 0]))
    yaw = float(np.arctan2(T[0, 1], T[0, 0]))
    V = xy[hull.vertices]
    E = np.roll(V, -1, axis=0) - V
    L = np.linalg.norm(E, axis=1)
    off = (np.arctan2(E[:, 1], E[:, 0]) - yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4
    sel = (np.abs(off) <= PARALLEL_SIDES_RAD) & (L > 0)
    if sel.any():
        yaw += float(np.sum(L[sel] * off[sel]) / np.sum(L[sel]))
    return yaw


def upright_oriented_box(points: np.ndarray) -> OrientedBox:
    """Tight gravity-upright box of points in a +Z-up frame.

    Footprint: the minimum-area rectangle of the points' XY (``trimesh.bounds.oriented_bounds_2D``);
    height: the Z extent. Box +X along the longer horizontal side (``length >= width``), box +Z =
    frame +Z, yaw normalised to (-90, 90] degrees. An upright box, not trimesh's free
    minimum-volume box, because objects stand on the floor and answers carry one heading about the
    vertical.
    """
    P = _points(points)
    xy = P[:, :2]
    yaw = _min_area_yaw(xy)
    for _ in range(2):
        c, s = np.cos(yaw), np.sin(yaw)
        u, v = xy @ np.array([c, s]), xy @ np.array([-s, c])
        if u.max() - u.min() >= v.max() - v.min():
            break
        yaw += np.pi / 2
    yaw = float(np.arctan2(np.sin(yaw), np.cos(yaw)))  # (-pi, pi]
    if yaw > np.pi / 2:
        yaw -= np.pi
    elif yaw <= -np.pi / 2:
        yaw += np.pi
    c, s = np.cos(yaw), np.sin(yaw)
    ex, ey = np.array([c, s]), np.array([-s, c])
    u, v = xy @ ex, xy @ ey
    center_xy = (u.max() + u.min()) / 2 * ex + (v.max() + v.min()) / 2 * ey
    z0, z1 = P[:, 2].min(), P[:, 2].max()
    return OrientedBox(np.array([center_xy[0], center_xy[1], (z0 + z1) / 2]), yaw_matrix(yaw),
                       np.array([u.max() - u.min(), v.max() - v.min(), z1 - z0]))
