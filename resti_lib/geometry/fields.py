"""Fields a box or a pose is drawn in: rotations about an axis, headings about the up axis, an
exact rotation that prints as a given matrix, the gaze point of cameras that look at one place,
and the coordinates of a centre (cartesian, projective: image-plane direction and depth, or height
below the camera). The option stage (:mod:`resti_lib.options.kinds`) draws candidates in them."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from .frames import nearest_rotation


def rot(axis, deg: float) -> np.ndarray:
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(a / np.linalg.norm(a) * np.radians(deg)).as_matrix()


PREIMAGE_BATCH = 64   # perturbations of a rotation drawn and printed at once


def rotation_preimage(printed, decimals: int, rng: np.random.Generator, *, accept=None, tries: int = 3000,
                      signed_zero: bool = False) -> np.ndarray:
    """An exact rotation whose entries print as ``printed`` at ``decimals`` (and that ``accept``
    takes, e.g. its printed heading): every field a perturbation leaves alone then prints exactly
    as in the answer. ``signed_zero``: the printer keeps the sign of a zero, so an entry printed ``-0.0``
    is below zero and one printed ``0.0`` is not."""
    P = np.asarray(printed, float)
    R = nearest_rotation(P)
    p = np.round(P, decimals)

    def wrong(Q):  # (..., 3, 3) -> (...) how many entries of each print otherwise than P's
        q = np.round(Q, decimals)
        bad = q != p
        return (bad | (np.signbit(q) != np.signbit(p)) if signed_zero else bad).sum(axis=(-2, -1))

    def ok(Q):
        return wrong(Q) == 0 and (accept is None or accept(Q))

    if ok(R):
        return R
    sigma = 0.6 * 10.0 ** -decimals
    for s in range(0, tries, PREIMAGE_BATCH):  # the draws in batches, tried in their order
        Qs = Rotation.from_rotvec(rng.normal(0.0, sigma, (min(PREIMAGE_BATCH, tries - s), 3))).as_matrix() @ R
        for i in np.flatnonzero(wrong(Qs) == 0):
            if accept is None or accept(Qs[i]):
                return Qs[i]
    # none of the draws about the nearest rotation prints so (several entries near a cell's edge, or the sign
    # of several zeros): a walk that never prints more entries wrong than its last step
    Q, bad = R, wrong(R)
    for k in range(tries):  # steps from the cell's width down to a thirtieth of it, in turn
        Q1 = Rotation.from_rotvec(rng.normal(0.0, sigma * 0.3 ** (k % 4), 3)).as_matrix() @ Q
        b1 = wrong(Q1)
        if b1 <= bad:
            Q, bad = Q1, b1
            if bad == 0 and ok(Q):
                return Q
    return R


def heading_deg(R, up, col: int) -> float:
    """Heading of column ``col`` of a rotation about the world ``up`` axis (degrees)."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    e1 = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 1.0, 0.0]) - up[1] * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    v = np.asarray(R, float)[:, col]
    return float(np.degrees(np.arctan2(v @ e2, v @ e1)))


def _up_alignment(up) -> np.ndarray:
    """The rotation that takes the world ``up`` axis to +Z (identity for +Z up)."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    if np.allclose(up, [0.0, 0.0, 1.0]):
        return np.eye(3)
    return Rotation.align_vectors([[0.0, 0.0, 1.0]], [up])[0].as_matrix()


def yaw_tilt(R, up) -> np.ndarray:
    """A rotation as its heading about the world ``up`` axis and two gravity-referenced tilt angles
    (radians): the intrinsic z-y-x angles of ``R`` in a world frame with ``up`` as +Z. The tilts say
    how far the camera leans from level (for a camera they are its pitch and roll, in its own axis
    convention); the heading alone changes as it turns about the vertical."""
    A = _up_alignment(up)
    return Rotation.from_matrix(A @ nearest_rotation(np.asarray(R, float))).as_euler("ZYX")


def from_yaw_tilt(angles, up) -> np.ndarray:
    """The rotation of :func:`yaw_tilt` angles (its inverse)."""
    A = _up_alignment(up)
    return A.T @ Rotation.from_euler("ZYX", np.asarray(angles, float)).as_matrix()


def horizontal_frame(R, up, col: int = 2) -> np.ndarray:
    """Columns: horizontal forward (column ``col`` projected), left, up — a premise's heading frame."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    f = np.asarray(R, float)[:, col] - (np.asarray(R, float)[:, col] @ up) * up
    if np.linalg.norm(f) < 1e-6:
        f = np.array([1.0, 0.0, 0.0]) - up[0] * up
    f /= np.linalg.norm(f)
    return np.column_stack([f, np.cross(up, f), up])


def concentrated_axis(rotations) -> int:
    """The box axis (column of the box-to-camera rotations) whose direction in the camera frame is most
    concentrated over ``rotations``, whatever its sign: the largest top eigenvalue of the mean outer product of
    that column. Objects standing on a surface keep their up axis along the surface's normal as the cameras see
    it, and turn about it (v5: ScanNet and Waymo boxes, axis 2, 0.96 and 1.0; Omni6DPose objects, axis 1, 0.70
    against 0.42 and 0.50)."""
    Rs = np.asarray(rotations, float).reshape(-1, 3, 3)
    conc = [float(np.linalg.eigvalsh(Rs[:, :, k].T @ Rs[:, :, k] / len(Rs))[-1]) for k in range(3)]
    return int(np.argmax(conc))


def box_yaw(R, up_axis: int) -> float:
    """Heading of a box about its local ``up_axis`` (``box_yaw(R @ rot(e_up, d)) == box_yaw(R) + d``)."""
    R = np.asarray(R, float)
    up = R[:, up_axis]
    f = np.array([0.0, 0.0, 1.0]) - up[2] * up
    if np.linalg.norm(f) < 1e-6:
        f = np.array([1.0, 0.0, 0.0]) - up[0] * up
    f /= np.linalg.norm(f)
    g = np.cross(up, f)
    a = R[:, (up_axis + 1) % 3]
    return float(np.degrees(np.arctan2(a @ g, a @ f)))


DOWN = np.array([0.0, 1.0, 0.0])  # +Y down in the reference camera's OpenCV axes


def gaze_depth(R, t) -> float:
    """Depth along the reference optical axis (+Z) of its closest approach to this camera's optical
    axis; NaN when the two are parallel or the point is not in front."""
    a = np.array([0.0, 0.0, 1.0])
    b = np.asarray(R, float)[:, 2]
    t = np.asarray(t, float)
    c = a @ b
    den = 1.0 - c * c
    if den < 1e-4:
        return float("nan")
    s = (t @ a - c * (t @ b)) / den
    return float(s) if 0.05 < s < 50.0 else float("nan")


def gaze_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(DOWN, u)
    if np.linalg.norm(e1) < 1e-9:
        e1 = np.cross(np.array([1.0, 0.0, 0.0]), u)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def level_rotation(x_axes) -> np.ndarray:
    """The rotation that takes the down of cameras held level to the frame's +Y: the direction most nearly
    perpendicular to every camera's x axis (``x_axes``, in the reference frame: the smallest eigenvector of
    their scatter), signed towards +Y; the identity when no direction stands out (its eigenvalue not under a
    quarter of the next). Hand-held cameras keep their x axis level: a reference camera pitched towards a desk
    has its +Y off the vertical (v5 Omni6DPose: by 39 degrees; the x axes' component along the found down
    spreads 0.2 between the 5th and 95th percentiles, along the reference's +Y 0.6), so an azimuth and a roll
    about its +Y turned with the camera's place on the desk."""
    X = np.asarray(x_axes, float).reshape(-1, 3)
    w, v = np.linalg.eigh(X.T @ X / max(len(X), 1))
    if len(X) < 3 or not w[0] < 0.25 * w[1]:
        return np.eye(3)
    d = v[:, 0] if v[1, 0] >= 0 else -v[:, 0]
    return Rotation.align_vectors([[0.0, 1.0, 0.0]], [d])[0].as_matrix()


def gaze_fields(R, t, G) -> np.ndarray:
    """A camera relative to a gaze point ``G`` (reference frame): its centre as seen from ``G`` (the log
    of its distance, the azimuth about the frame's vertical and the elevation, degrees; azimuth and
    elevation 0: on the reference camera's side, -Z from ``G``), the two angles of its optical axis
    away from the line towards ``G`` and its roll about the optical axis (degrees).
    Cameras around a desk look at it from about one distance: every candidate drawn this way does too
    (drawn as the centre's coordinates, a normal copula cannot keep them on that shell: v5 Omni6DPose
    distractors' distances to the gaze point spread 0.23 in log, the answers' 0.14)."""
    R, C = np.asarray(R, float), np.asarray(t, float)
    a = R[:, 2]
    u = np.asarray(G, float) - C
    u /= np.linalg.norm(u)
    e1, e2 = gaze_basis(u)
    au = max(float(a @ u), 1e-6)
    alpha, beta = np.degrees(np.arctan2(a @ e1, au)), np.degrees(np.arctan2(a @ e2, au))
    xr = np.cross(DOWN, a)
    xr /= np.linalg.norm(xr)
    yr = np.cross(a, xr)
    roll = np.degrees(np.arctan2(R[:, 0] @ yr, R[:, 0] @ xr))
    return np.array([*shell_fields(C - np.asarray(G, float)), alpha, beta, roll])


def shell_fields(v) -> np.ndarray:
    """An offset ``v`` as (log distance, azimuth, elevation) in degrees: azimuth about the frame's +Y
    (down) from -Z, elevation towards +Y."""
    v = np.asarray(v, float)
    r = max(float(np.linalg.norm(v)), 1e-9)
    return np.array([math.log(r), math.degrees(math.atan2(v[0], -v[2])), math.degrees(math.asin(max(-1.0, min(1.0, v[1] / r))))])


def shell_half_cells(f, h: float) -> list[float]:
    """Half widths of the printed cell (``h`` metres per coordinate) in the shell fields ``f`` of an offset
    (:func:`shell_fields`): log distance, azimuth and elevation (degrees), first order."""
    r = max(math.exp(float(f[0])), h)
    return [h / r, math.degrees(h / r), math.degrees(h / r)]


def from_shell_fields(f) -> np.ndarray:
    """The offset of :func:`shell_fields` (its inverse)."""
    r, az, el = math.exp(float(f[0])), math.radians(float(f[1])), math.radians(float(f[2]))
    return r * np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


def from_gaze_fields(f, G) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`gaze_fields`: (R, t)."""
    f = np.asarray(f, float)
    C = np.asarray(G, float) + from_shell_fields(f[:3])
    u = np.asarray(G, float) - C
    u /= np.linalg.norm(u)
    e1, e2 = gaze_basis(u)
    a = u + np.tan(np.radians(f[3])) * e1 + np.tan(np.radians(f[4])) * e2
    a /= np.linalg.norm(a)
    xr = np.cross(DOWN, a)
    xr /= np.linalg.norm(xr)
    yr = np.cross(a, xr)
    x = np.cos(np.radians(f[5])) * xr + np.sin(np.radians(f[5])) * yr
    return np.column_stack([x, np.cross(a, x), a]), C


def centre_fields(c, mode: str, power=(1.0, 1.0)) -> np.ndarray:
    """A box centre as drawn: projective (x/z^px, y/z^py, log z), height (x/z^px, y, log z) or cartesian.

    ``power``: the depth exponents (px, py) of the image-plane coordinates (1: the direction x/z; 0: the
    metres; :func:`resti_lib.options.kinds.box.depth_exponent` fits them per group)."""
    c = np.asarray(c, float)
    px, py = power
    if mode == "projective":
        return np.array([c[0] / c[2] ** px, c[1] / c[2] ** py, math.log(c[2])])
    if mode == "height":
        return np.array([c[0] / c[2] ** px, c[1], math.log(c[2])])
    return c.copy()


def centre_from_fields(f, mode: str, power=(1.0, 1.0)) -> np.ndarray:
    f = np.asarray(f, float)
    px, py = power
    if mode == "projective":
        z = math.exp(f[2])
        return np.array([f[0] * z ** px, f[1] * z ** py, z])
    if mode == "height":
        z = math.exp(f[2])
        return np.array([f[0] * z ** px, f[1], z])
    return f.copy()


def centre_half_cells(c, mode: str, ulp: float, power=(1.0, 1.0)) -> np.ndarray:
    """Half width of the printed rounding cell of each centre field (first-order)."""
    z = abs(float(c[2])) or 1.0
    h = 0.5 * ulp
    px, py = power
    if mode == "projective":
        return np.array([h / z ** px, h / z ** py, h / z])
    if mode == "height":
        return np.array([h / z ** px, h, h / z])
    return np.array([h, h, h])
