"""Small helpers shared by the mini-world writers: seeded RNG, rigid transforms, stable output.

Nothing here is an audit operator: these are the generator's own few lines of numpy, so the
mini-world's truth never depends on the code it is meant to test.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

# --------------------------------------------------------------------------------------- seeding


def stable_seed(seed: int, key: str) -> int:
    """A 64-bit seed from ``seed`` and a text key via sha256 (never Python's salted ``hash``).

    Parameters
    ----------
    seed : int
        The world seed.
    key : str
        A stable text key, e.g. ``"row|scene0900_00.mp4|Pose Estimation|3"``.

    Returns
    -------
    int
        Seed for :func:`numpy.random.default_rng`.
    """
    digest = hashlib.sha256(f"{int(seed)}|{key}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


def rng_for(seed: int, key: str) -> np.random.Generator:
    """``numpy.random.default_rng(stable_seed(seed, key))``."""
    return np.random.default_rng(stable_seed(seed, key))


# ------------------------------------------------------------------------------ rigid transforms


def rot_x(a: float) -> np.ndarray:
    """Rotation about +X by ``a`` radians (3x3)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation about +Y by ``a`` radians (3x3)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation about +Z by ``a`` radians (3x3)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_z_batch(a: np.ndarray) -> np.ndarray:
    """Rotations about +Z for an array of angles, shape ``(n, 3, 3)``."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    R[..., 2, 2] = 1.0
    return R


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 (or batched ``(..., 4, 4)``) rigid transform from rotation(s) and translation(s)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transform(s) via the transpose of the rotation block."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = np.swapaxes(R, -1, -2)
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def apply_T(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points ``p`` of shape ``(..., 3)``."""
    p = np.asarray(p, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


#: OpenCV camera axes from Waymo camera axes: ``x_cv = -y_w, y_cv = -z_w, z_cv = x_w``.
R_CV_FROM_WAYMO = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: ``T_waymo_cam_from_cv_cam`` (4x4).
T_WAYMO_FROM_CV = make_T(R_CV_FROM_WAYMO.T, np.zeros(3))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


_UP = np.array([0.0, 0.0, 1.0])


def look_rotation(forward: np.ndarray, up: np.ndarray = _UP, roll: float = 0.0) -> np.ndarray:
    """``R_world_from_cam`` for an OpenCV camera looking along ``forward`` (z-up world).

    Columns are the camera's +X (right), +Y (down) and +Z (forward) in world coordinates; ``roll``
    (radians) turns the image about the optical axis.
    """
    z = np.asarray(forward, dtype=np.float64)
    z = z / math.sqrt(z @ z)
    x = _cross(z, np.asarray(up, dtype=np.float64))
    x = x / math.sqrt(x @ x)
    y = _cross(z, x)
    R = np.stack([x, y, z], axis=1)
    return R @ rot_z(roll)


def quat_wxyz_from_matrix(R: np.ndarray) -> list[float]:
    """Unit quaternion (w, x, y, z), w >= 0, from a rotation matrix (largest-diagonal branch)."""
    R = np.asarray(R, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return [float(v) for v in q]


# --------------------------------------------------------------------------------- small geometry


def project(K: tuple[float, float, float, float], p_cam: np.ndarray) -> np.ndarray:
    """Pinhole projection ``(u, v)`` of OpenCV camera-frame points ``(..., 3)``."""
    fx, fy, cx, cy = K
    z = p_cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([fx * p_cam[..., 0] / z + cx, fy * p_cam[..., 1] / z + cy], axis=-1)


def in_view(
    K: tuple[float, float, float, float],
    size: tuple[int, int],
    p_cam: np.ndarray,
    *,
    margin: float = 0.08,
    min_depth: float = 0.3,
    max_depth: float = np.inf,
) -> np.ndarray:
    """True where a camera-frame point lies in front of the camera and inside the image.

    ``margin`` is a fraction of the image size kept free at every border.
    """
    w, h = size
    uv = project(K, p_cam)
    z = p_cam[..., 2]
    with np.errstate(invalid="ignore"):
        ok = (z > min_depth) & (z < max_depth)
        ok &= (uv[..., 0] > margin * w) & (uv[..., 0] < (1 - margin) * w)
        ok &= (uv[..., 1] > margin * h) & (uv[..., 1] < (1 - margin) * h)
    return ok


def box_corners(center: np.ndarray, size: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of a box with centre, edge lengths and rotation (box -> frame)."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    local = signs * (np.asarray(size, float) / 2.0)
    if R is not None:
        local = local @ np.asarray(R, float).T
    return local + np.asarray(center, float)


def point_box_distance(
    p: np.ndarray, center: np.ndarray, size: np.ndarray, R: np.ndarray | None = None
) -> float:
    """Euclidean distance from point ``p`` to the solid box (0 inside)."""
    d = np.asarray(p, float) - np.asarray(center, float)
    if R is not None:
        d = np.asarray(R, float).T @ d
    excess = np.maximum(np.abs(d) - np.asarray(size, float) / 2.0, 0.0)
    return float(np.linalg.norm(excess))


def tight_upright_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(center, R, lwh)`` of the tight gravity-upright box of a box instance's vertices ``(N, 3)``
    in a +Z-up frame (its footprint: four distinct corners).

    The generator's own computation (not the audit's): every direction joining two footprint
    points is tried (the minimum-area rectangle has a side along a hull side, which joins two
    points) and the one whose XY-projection rectangle has the least area wins; the footprint's
    four sides (corners ordered by angle about their centroid) that run within 1e-4 rad of it,
    modulo 90 degrees, give the yaw as their length-weighted mean direction (so float32 noise in
    the corners cannot pick one side over another). Box +X runs along the longer side, its yaw in
    (-90, 90] degrees; height = Z extent.
    """
    P = np.asarray(points, float)
    xy = P[:, :2]
    i, j = np.triu_indices(len(xy), 1)
    e = xy[j] - xy[i]
    n = np.linalg.norm(e, axis=1)
    e = e[n > 1e-12] / n[n > 1e-12, None]
    u = e @ xy.T
    v = np.stack([-e[:, 1], e[:, 0]], axis=1) @ xy.T
    area = (u.max(1) - u.min(1)) * (v.max(1) - v.min(1))
    yaw = float(np.arctan2(*e[int(np.argmin(area))][::-1]))
    corners = np.unique(xy, axis=0)
    mid = corners.mean(axis=0)
    corners = corners[np.argsort(np.arctan2(corners[:, 1] - mid[1], corners[:, 0] - mid[0]))]
    sides = np.roll(corners, -1, axis=0) - corners
    lens = np.linalg.norm(sides, axis=1)
    off = (np.arctan2(sides[:, 1], sides[:, 0]) - yaw + math.pi / 4) % (math.pi / 2) - math.pi / 4
    par = np.abs(off) <= 1e-4
    if par.any():
        yaw += float(np.sum(lens[par] * off[par]) / np.sum(lens[par]))
    ex = np.array([np.cos(yaw), np.sin(yaw)])
    ey = np.array([-ex[1], ex[0]])
    if np.ptp(xy @ ex) < np.ptp(xy @ ey):
        yaw += math.pi / 2
    yaw = math.atan2(math.sin(yaw), math.cos(yaw))
    if yaw > math.pi / 2:
        yaw -= math.pi
    elif yaw <= -math.pi / 2:
        yaw += math.pi
    R = rot_z(yaw)
    ex, ey = R[:2, 0], R[:2, 1]
    a, b = xy @ ex, xy @ ey
    cxy = (a.max() + a.min()) / 2 * ex + (b.max() + b.min()) / 2 * ey
    z0, z1 = P[:, 2].min(), P[:, 2].max()
    return np.array([cxy[0], cxy[1], (z0 + z1) / 2]), R, np.array([np.ptp(a), np.ptp(b), z1 - z0])


def aabb_distance(min_a: np.ndarray, max_a: np.ndarray, min_b: np.ndarray, max_b: np.ndarray) -> float:
    """Minimum distance between two axis-aligned boxes (0 when they touch or overlap)."""
    gap = np.maximum(0.0, np.maximum(np.asarray(min_a) - max_b, np.asarray(min_b) - max_a))
    return float(np.linalg.norm(gap))


def wrap_deg(a: float) -> float:
    """Wrap degrees to [-180, 180)."""
    return float((a + 180.0) % 360.0 - 180.0)


def horizontal_heading_change(f0: np.ndarray, f1: np.ndarray, up: np.ndarray) -> float:
    """Signed angle (degrees, CCW about ``up``) between the horizontal projections of f0 and f1."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    h0 = f0 - up * (up @ f0)
    h1 = f1 - up * (up @ f1)
    h0 = h0 / np.linalg.norm(h0)
    h1 = h1 / np.linalg.norm(h1)
    return wrap_deg(math.degrees(math.atan2(float(up @ np.cross(h0, h1)), float(h0 @ h1))))


def smoothstep(x: np.ndarray) -> np.ndarray:
    """C1 ramp from 0 (x <= 0) to 1 (x >= 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


# ----------------------------------------------------------------------------- stable file output


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps(obj: Any, *, indent: int | None = None) -> str:
    """JSON text with sorted keys (the only JSON writer of the generator)."""
    return json.dumps(
        obj, sort_keys=True, indent=indent, default=_json_default, ensure_ascii=False, allow_nan=False
    )


def write_json(path: Path, obj: Any, *, indent: int | None = None) -> None:
    """Write ``obj`` as sorted-key JSON (UTF-8, trailing newline)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps(obj, indent=indent) + "\n", encoding="utf-8")


def write_parquet(path: Path, table: pa.Table) -> None:
    """Write a parquet file with fixed settings so reruns are byte-identical."""
    path.parent.mkdir(parents=True, exist_ok=True)
    table = table.replace_schema_metadata(None)
    pq.write_table(
        table,
        path,
        compression="snappy",
        use_dictionary=False,
        write_statistics=True,
        row_group_size=1 << 20,
        data_page_version="1.0",
    )


def round_list(v, nd: int = 6) -> list:
    """Nested lists of Python floats rounded to ``nd`` decimals (for world.json)."""
    return np.round(np.asarray(v, dtype=np.float64), nd).tolist()
