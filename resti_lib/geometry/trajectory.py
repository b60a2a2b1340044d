"""Pose tracks and vectorised trajectory operators.

A :class:`PoseTrack` is a timestamped sequence of rigid poses ``T_world_from_entity`` (4x4, see
:mod:`resti_lib.geometry.frames` for the matrix direction). Times are seconds on the sequence's
own timeline, positions metres, angles degrees in every returned value.

Every operator returns ``(value, evidence)`` where ``evidence`` is a small JSON-friendly dict naming
the sample indices and timestamps used, the interpolation rule, and any shortening of the
interval. Operators follow three rules:

- **No interpolation over invalid poses.** A pose is invalid when any entry is non-finite
  (``PoseTrack.valid``). Linear interpolation between two samples requires both to be valid.
- **Trailing invalid poses shorten the interval.** When ``t1`` lies after the last valid sample
  (the sequence ends in invalid poses), the interval becomes ``[t0, t_last_valid]`` and the
  evidence says ``"shortened_to": t_last_valid`` (see :func:`interval_valid`).
- **Errors, not guesses.** A time out of range, an invalid pose at an asked time, or invalid
  samples inside a path interval raise :class:`resti_lib.errors.ContractError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from resti_lib.errors import ContractError, InputError, SourceError, SourceGapError

__all__ = [
    "PoseTrack",
    "acceleration",
    "average_speed",
    "average_velocity",
    "endpoint_displacement",
    "heading_change",
    "horizontal_heading_deg",
    "interval_valid",
    "legacy_plane_angle",
    "path_length",
    "pose_at",
    "positions_at",
    "segment_turns",
    "wrap_deg",
]

DEFAULT_TOL = 1e-6  # seconds: a time within this of a sample is that sample
_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass
class PoseTrack:
    """A timestamped pose sequence ``T_world_from_entity``.

    Parameters
    ----------
    times : float64 array ``[N]``
        Seconds on the sequence's own timeline, strictly increasing.
    T : float64 array ``[N, 4, 4]``
        ``T_world_from_entity`` per sample (for cameras: OpenCV camera axes).
    name : str
        What the track is (``"scene0012_00 camera"``, ``"<segment> vehicle"``), for evidence.
    source : str
        The file(s) the poses were read from, for evidence.
    valid : bool array ``[N]``, optional
        Computed as "all 16 entries finite"; a given mask is AND-ed with that.
    meta : dict
        Free-form extras from the reader (frame numbers, micros, box sizes ...).
    max_gap_factor : float, optional
        Samples inside a question's window further apart than this multiple of the track's median
        sampling interval are a gap (:meth:`check_gap`); default ``max_gap_factor`` of
        ``params/measure.yaml``.
    """

    times: np.ndarray
    T: np.ndarray
    name: str = ""
    source: str = ""
    valid: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    max_gap_factor: float | None = None
    _quat: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _invalid_cum: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)
    _step: float = field(default=0.0, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        self.T = np.asarray(self.T, dtype=np.float64)
        n = self.times.shape[0]
        if self.T.shape != (n, 4, 4):
            raise InputError(f"poses must have shape [{n}, 4, 4], got {self.T.shape}",
                             file=self.source or None, field="T")
        if n == 0:
            raise InputError("empty pose track", file=self.source or None, field="times")
        if not np.isfinite(self.times).all():
            i = int(np.argmin(np.isfinite(self.times)))
            raise InputError("non-finite timestamp", file=self.source or None, row=i, field="times")
        d = np.diff(self.times)
        if (d <= 0).any():
            i = int(np.argmax(d <= 0)) + 1
            raise SourceError(f"timestamps must be strictly increasing (t[{i - 1}]={self.times[i - 1]!r}, "
                              f"t[{i}]={self.times[i]!r})", file=self.source or None, row=i, field="times")
        if self.max_gap_factor is None:
            from ..defaults import setting

            self.max_gap_factor = float(setting(None, "max_gap_factor"))
        self._step = float(np.median(d)) if d.size else 0.0
        finite = np.isfinite(self.T).all(axis=(1, 2))
        self.valid = finite if self.valid is None else (np.asarray(self.valid, bool).reshape(-1) & finite)

    def __len__(self) -> int:
        return self.times.shape[0]

    def check_gap(self, t0: float, t1: float) -> None:
        """Refuse a window ``[t0, t1]`` (an instant when equal) whose samples, with the ones that
        bracket it, lie further apart than ``max_gap_factor`` times the track's median sampling
        interval (:class:`~resti_lib.errors.SourceGapError`: a gap is excluded, never interpolated)."""
        n = len(self)
        if n < 3:
            return
        i0 = max(int(np.searchsorted(self.times, t0, side="right")) - 1, 0)
        i1 = min(int(np.searchsorted(self.times, t1, side="left")), n - 1)
        if i1 <= i0:
            return
        d = np.diff(self.times[i0:i1 + 1])
        step = self._step
        k = int(np.argmax(d))
        if d[k] > self.max_gap_factor * step:
            raise SourceGapError(f"{self.name}: no sample between t={self.times[i0 + k]:.6f} s and "
                                 f"t={self.times[i0 + k + 1]:.6f} s ({d[k]:.3f} s, {d[k] / step:.1f} times the "
                                 f"sampling interval {step:.4f} s; max_gap_factor {self.max_gap_factor:g}) inside "
                                 f"[{t0:.6f}, {t1:.6f}] s", file=self.source or None, row=i0 + k + 1, field="times")

    @property
    def positions(self) -> np.ndarray:
        """Entity origins in the world, ``[N, 3]`` (metres)."""
        return self.T[:, :3, 3]

    @property
    def rotations(self) -> np.ndarray:
        """``R_world_from_entity``, ``[N, 3, 3]``."""
        return self.T[:, :3, :3]

    @property
    def quat_xyzw(self) -> np.ndarray:
        """Unit quaternions (scalar-last) of the rotations, NaN rows for invalid poses; cached."""
        if self._quat is None:
            q = np.full((len(self), 4), np.nan)
            if self.valid.any():
                q[self.valid] = Rotation.from_matrix(self.rotations[self.valid]).as_quat()
            self._quat = q
        return self._quat

    @property
    def invalid_cum(self) -> np.ndarray:
        """``[N + 1]`` counts of invalid samples before each index (cached), for O(1) range counts."""
        if self._invalid_cum is None:
            self._invalid_cum = np.concatenate([[0], np.cumsum(~self.valid)])
        return self._invalid_cum

    @property
    def last_valid_index(self) -> int | None:
        """Index of the last valid sample, None when no sample is valid."""
        cum = self.invalid_cum
        n = len(self)
        if cum[-1] == n:
            return None
        # trailing invalid run: the samples after the last valid one are all invalid
        k = n - 1
        if self.valid[k]:
            return k
        return int(np.flatnonzero(self.valid)[-1])

    def describe(self) -> dict:
        """Small evidence dict naming the track."""
        return {"track": self.name, "source": self.source}


def wrap_deg(a: float | np.ndarray) -> float | np.ndarray:
    """Wrap degrees to ``[-180, 180)``."""
    w = (np.asarray(a, dtype=np.float64) + 180.0) % 360.0 - 180.0
    return float(w) if np.ndim(w) == 0 else w


# ---------------------------------------------------------------------------------------------
# locating times

_OK, _OUT_OF_RANGE, _NO_SAMPLE, _INVALID = 0, 1, 2, 3
_REASON = {
    _OUT_OF_RANGE: "time outside the track",
    _NO_SAMPLE: "no sample within tolerance",
    _INVALID: "invalid (non-finite) pose",
}


def _locate(track: PoseTrack, t: np.ndarray, rule: str, tol: float):
    """Vectorised bracket search: ``(i0, i1, alpha, status)`` for times ``t`` (any shape)."""
    times = track.times
    n = times.shape[0]
    t = np.asarray(t, dtype=np.float64)
    status = np.zeros(t.shape, dtype=np.int8)
    j = np.searchsorted(times, t)  # first index with times[j] >= t
    lo = np.clip(j - 1, 0, n - 1)
    hi = np.clip(j, 0, n - 1)
    d_lo = np.abs(t - times[lo])
    d_hi = np.abs(times[hi] - t)
    pick = np.where(d_lo <= d_hi, lo, hi)
    dist = np.minimum(d_lo, d_hi)
    out = (t < times[0] - tol) | (t > times[-1] + tol) | ~np.isfinite(t)
    if rule in ("exact", "nearest"):
        i0 = i1 = pick
        alpha = np.zeros(t.shape)
        status[dist > tol] = _NO_SAMPLE
    elif rule == "linear":
        snap = dist <= tol
        i1 = np.where(snap, pick, hi)
        i0 = np.where(snap, pick, lo)
        span = times[i1] - times[i0]
        with np.errstate(invalid="ignore", divide="ignore"):
            alpha = np.where(snap | (span <= 0), 0.0, (t - times[i0]) / np.where(span > 0, span, 1.0))
        alpha = np.clip(alpha, 0.0, 1.0)
        i1 = np.where(alpha == 0.0, i0, i1)
    else:
        raise ValueError(f"unknown rule {rule!r} (exact | nearest | linear)")
    valid = track.valid
    status[(status == _OK) & ~(valid[i0] & valid[i1])] = _INVALID
    status[out] = _OUT_OF_RANGE
    return i0, i1, alpha, status


def _raise_status(track: PoseTrack, t: np.ndarray, i0, i1, status, rule: str, tol: float) -> None:
    bad = np.flatnonzero(status.reshape(-1))
    if bad.size == 0:
        return
    k = int(bad[0])
    tk = float(np.asarray(t, dtype=np.float64).reshape(-1)[k])
    code = int(status.reshape(-1)[k])
    i0k, i1k = int(np.asarray(i0).reshape(-1)[k]), int(np.asarray(i1).reshape(-1)[k])
    where = f"{track.name or 'track'} ({track.source})" if track.source else (track.name or "track")
    extra = ""
    if code == _OUT_OF_RANGE:
        extra = f" [{track.times[0]:.6f}, {track.times[-1]:.6f}] s"
    elif code == _NO_SAMPLE:
        extra = f" (rule {rule!r}, tol {tol:g} s, nearest sample t={track.times[i0k]:.6f} s)"
    elif code == _INVALID:
        extra = f" at sample(s) {sorted({i0k, i1k})}"
    raise ContractError(f"{where}: t={tk:.6f} s: {_REASON[code]}{extra}")


def _slerp_matrices(track: PoseTrack, i0: np.ndarray, i1: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Rotation matrices slerped between samples ``i0`` and ``i1`` at fractions ``alpha``."""
    q = track.quat_xyzw
    q0 = q[i0]
    q1 = q[i1]
    dot = np.einsum("...i,...i->...", q0, q1)
    q1 = np.where(dot[..., None] < 0, -q1, q1)
    dot = np.abs(dot)
    omega = np.arccos(np.clip(dot, -1.0, 1.0))
    so = np.sin(omega)
    small = so < 1e-9
    with np.errstate(invalid="ignore", divide="ignore"):
        w0 = np.where(small, 1.0 - alpha, np.sin((1.0 - alpha) * omega) / np.where(small, 1.0, so))
        w1 = np.where(small, alpha, np.sin(alpha * omega) / np.where(small, 1.0, so))
    qi = w0[..., None] * q0 + w1[..., None] * q1
    qi /= np.linalg.norm(qi, axis=-1, keepdims=True)
    x, y, z, w = qi[..., 0], qi[..., 1], qi[..., 2], qi[..., 3]
    R = np.empty(qi.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def pose_at(track: PoseTrack, t: float | np.ndarray, rule: str = "linear", tol: float = DEFAULT_TOL,
            *, errors: str = "raise") -> tuple[np.ndarray, dict]:
    """Pose(s) ``T_world_from_entity`` at time(s) ``t``.

    Parameters
    ----------
    track : PoseTrack
    t : float or array
        Seconds on the track's timeline.
    rule : {"exact", "nearest", "linear"}
        ``exact``: the sample within ``tol`` of ``t``. ``nearest``: the nearest sample, provided it
        lies within ``tol`` (pass ``tol=np.inf`` for an unbounded nearest). ``linear``: translation
        lerp and rotation slerp between the two bracketing samples (both must be valid); a time
        within ``tol`` of a sample returns that sample unchanged.
    tol : float
        Seconds. Also the slack allowed beyond the first/last sample.
    errors : {"raise", "nan"}
        For array ``t``: raise on the first failing time, or return NaN poses there.

    Returns
    -------
    T : ``[4, 4]`` for scalar ``t``, else ``[..., 4, 4]``.
    evidence : dict
        ``rule``, ``indices`` and ``times`` of the samples used and ``alpha`` (scalar ``t``), or
        counts (array ``t``).

    Raises
    ------
    ContractError
        Time out of range, no sample within ``tol``, or an invalid pose needed.
    """
    t_arr = np.asarray(t, dtype=np.float64)
    i0, i1, alpha, status = _locate(track, t_arr, rule, tol)
    if errors == "raise":
        _raise_status(track, t_arr, i0, i1, status, rule, tol)
    if t_arr.ndim == 0 and status == _OK:
        track.check_gap(float(t_arr), float(t_arr))
    T = track.T[i0].copy()
    interp = (alpha > 0.0) & (status == _OK)
    if interp.any():
        a = alpha[interp]
        T[interp, :3, 3] = (1.0 - a)[:, None] * track.T[i0[interp], :3, 3] + a[:, None] * track.T[i1[interp], :3, 3]
        T[interp, :3, :3] = _slerp_matrices(track, i0[interp], i1[interp], a)
    if (status != _OK).any():
        T[status != _OK] = np.nan
    if t_arr.ndim == 0:
        ev = {"rule": rule, "t": float(t_arr), "indices": sorted({int(i0), int(i1)}),
              "times": sorted({float(track.times[i0]), float(track.times[i1])}), "alpha": float(alpha)}
        return T, ev
    return T, {"rule": rule, "n": int(t_arr.size), "n_failed": int((status != _OK).sum())}


def positions_at(track: PoseTrack, t: float | np.ndarray, rule: str = "linear",
                 tol: float = DEFAULT_TOL) -> tuple[np.ndarray, dict]:
    """Entity position(s) at time(s) ``t`` (translation only; same rules as :func:`pose_at`)."""
    t_arr = np.asarray(t, dtype=np.float64)
    i0, i1, alpha, status = _locate(track, t_arr, rule, tol)
    _raise_status(track, t_arr, i0, i1, status, rule, tol)
    p = (1.0 - alpha)[..., None] * track.T[i0, :3, 3] + alpha[..., None] * track.T[i1, :3, 3]
    p = np.where((alpha == 0.0)[..., None], track.T[i0, :3, 3], p)
    if t_arr.ndim == 0:
        return p, {"rule": rule, "t": float(t_arr), "indices": sorted({int(i0), int(i1)}),
                   "times": sorted({float(track.times[i0]), float(track.times[i1])}), "alpha": float(alpha)}
    return p, {"rule": rule, "n": int(t_arr.size)}


# ---------------------------------------------------------------------------------------------
# intervals


def interval_valid(track: PoseTrack, t0: float, t1: float, *, tol: float = DEFAULT_TOL
                   ) -> tuple[tuple[float, float], dict]:
    """Check ``[t0, t1]`` against the track; shorten it when the sequence ends in invalid poses.

    When ``t1`` lies after the last valid sample (all later samples invalid), the interval becomes
    ``[t0, t_last_valid]`` and the evidence carries ``shortened_to`` (and ``shortened_from``).
    Nothing is interpolated over invalid poses. Invalid samples strictly inside the interval are
    counted in ``invalid_inside`` (path operators refuse them, endpoint operators ignore them).

    Returns
    -------
    (t0, t1_used), evidence

    Raises
    ------
    ContractError
        ``t1 < t0``; an end outside the track; no valid pose; the shortened interval is empty.
    """
    t0 = float(t0)
    t1 = float(t1)
    times = track.times
    ev: dict[str, Any] = {"t0": t0, "t1": t1}
    if not (np.isfinite(t0) and np.isfinite(t1)):
        raise ContractError(f"{track.name}: non-finite interval [{t0}, {t1}]")
    if t1 < t0:
        raise ContractError(f"{track.name}: interval end {t1} s before its start {t0} s")
    for tt in (t0, t1):
        if tt < times[0] - tol or tt > times[-1] + tol:
            raise ContractError(f"{track.name}: t={tt:.6f} s outside the track "
                                f"[{times[0]:.6f}, {times[-1]:.6f}] s")
    track.check_gap(t0, t1)
    last = track.last_valid_index
    if last is None:
        raise ContractError(f"{track.name}: no valid pose in the track")
    if t1 > times[last] + tol:
        t_last = float(times[last])
        if t_last <= t0 + tol and t1 > t0:
            raise ContractError(f"{track.name}: the interval [{t0:.6f}, {t1:.6f}] s lies in the trailing "
                                f"invalid poses (last valid t={t_last:.6f} s, sample {last})")
        ev.update({"shortened_to": t_last, "shortened_from": t1, "last_valid_index": last,
                   "reason": f"trailing invalid poses from sample {last + 1}"})
        t1 = t_last
    lo = int(np.searchsorted(times, t0 + tol, side="right"))  # first sample > t0 + tol
    hi = int(np.searchsorted(times, t1 - tol, side="left"))  # first sample >= t1 - tol
    n_bad = int(track.invalid_cum[max(hi, lo)] - track.invalid_cum[lo])
    if n_bad:
        ev["invalid_inside"] = n_bad
    ev["t1_used"] = t1
    return (t0, t1), ev


def _interval_samples(track: PoseTrack, t0: float, t1: float, rule: str, tol: float, gaps: str
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Times, positions and source indices of ``[p(t0), interior samples, p(t1)]``."""
    (t0, t1), ev = interval_valid(track, t0, t1, tol=tol)
    p_end, _ = positions_at(track, np.array([t0, t1]), rule, tol)
    times = track.times
    lo = int(np.searchsorted(times, t0 + tol, side="right"))
    hi = int(np.searchsorted(times, t1 - tol, side="left"))
    idx = np.arange(lo, max(hi, lo))
    bad = idx[~track.valid[idx]]
    if bad.size:
        if gaps == "error":
            raise ContractError(f"{track.name}: {bad.size} invalid pose(s) inside [{t0:.6f}, {t1:.6f}] s "
                                f"(first at t={times[bad[0]]:.6f} s, sample {int(bad[0])}); refusing to "
                                f"bridge them")
        if gaps != "skip":
            raise ValueError(f"gaps must be 'error' or 'skip', got {gaps!r}")
        ev["bridged_invalid_samples"] = [int(i) for i in bad[:20]]
        idx = idx[track.valid[idx]]
    ts = np.concatenate([[t0], times[idx], [t1]])
    ps = np.concatenate([p_end[:1], track.T[idx, :3, 3], p_end[1:]], axis=0)
    ev.update({"rule": rule, "n_interior_samples": int(idx.size)})
    if idx.size:
        ev["interior_index_range"] = [int(idx[0]), int(idx[-1])]
    return ts, ps, idx, ev


# ---------------------------------------------------------------------------------------------
# distances and rates


def endpoint_displacement(track: PoseTrack, t0: float, t1: float, *, rule: str = "linear",
                          tol: float = DEFAULT_TOL) -> tuple[float, dict]:
    """``|p(t1) - p(t0)|`` in metres (world frame of the track).

    Evidence: ``vector`` (``p(t1) - p(t0)``), sample ``indices`` at both ends, any shortening.
    """
    (t0, t1), ev = interval_valid(track, t0, t1, tol=tol)
    p0, e0 = positions_at(track, t0, rule, tol)
    p1, e1 = positions_at(track, t1, rule, tol)
    d = p1 - p0
    ev.update(track.describe())
    ev.update({"rule": rule, "indices_t0": e0["indices"], "indices_t1": e1["indices"],
               "sample_times_t0": e0["times"], "sample_times_t1": e1["times"], "vector": d.tolist()})
    return float(np.linalg.norm(d)), ev


def path_length(track: PoseTrack, t0: float, t1: float, *, rule: str = "linear",
                tol: float = DEFAULT_TOL, gaps: str = "error") -> tuple[float, dict]:
    """Integrated ``sum |Δp|`` over ``p(t0)``, the source samples strictly inside, and ``p(t1)``.

    Parameters
    ----------
    gaps : {"error", "skip"}
        Invalid samples inside the interval raise (default) or are skipped, i.e. bridged by a
        straight segment, which the evidence records as ``bridged_invalid_samples``.
    """
    _, ps, _, ev = _interval_samples(track, t0, t1, rule, tol, gaps)
    ev.update(track.describe())
    return float(np.linalg.norm(np.diff(ps, axis=0), axis=1).sum()), ev


def average_velocity(track: PoseTrack, t0: float, t1: float, *, rule: str = "linear",
                     tol: float = DEFAULT_TOL) -> tuple[float, dict]:
    """Magnitude of the average velocity ``|p(t1) - p(t0)| / (t1 - t0)`` in m/s.

    This is what legacy "average speed" questions computed; it is named for what it is.
    """
    d, ev = endpoint_displacement(track, t0, t1, rule=rule, tol=tol)
    dt = ev["t1_used"] - ev["t0"]
    if dt <= 0:
        raise ContractError(f"{track.name}: zero-length interval, average velocity undefined")
    ev.update({"statistic": "magnitude of average velocity = |p(t1) - p(t0)| / (t1 - t0)",
               "displacement_m": d, "dt_s": dt})
    return d / dt, ev


def average_speed(track: PoseTrack, t0: float, t1: float, *, rule: str = "linear",
                  tol: float = DEFAULT_TOL, gaps: str = "error") -> tuple[float, dict]:
    """Average speed ``path_length / (t1 - t0)`` in m/s."""
    L, ev = path_length(track, t0, t1, rule=rule, tol=tol, gaps=gaps)
    dt = ev["t1_used"] - ev["t0"]
    if dt <= 0:
        raise ContractError(f"{track.name}: zero-length interval, average speed undefined")
    ev.update({"statistic": "average speed = path length / (t1 - t0)", "path_length_m": L, "dt_s": dt})
    return L / dt, ev


def _sample_velocity(track: PoseTrack, i: int) -> tuple[np.ndarray, str, list[int]]:
    """Velocity at sample ``i``: central difference, one-sided where a neighbour is missing/invalid."""
    n = len(track)
    v = track.valid
    p = track.T[:, :3, 3]
    t = track.times
    if not v[i]:
        raise ContractError(f"{track.name}: invalid pose at sample {i}, velocity undefined")
    has_prev = i > 0 and v[i - 1]
    has_next = i < n - 1 and v[i + 1]
    if has_prev and has_next:
        a, b, scheme = i - 1, i + 1, "central"
    elif has_next:
        a, b, scheme = i, i + 1, "forward"
    elif has_prev:
        a, b, scheme = i - 1, i, "backward"
    else:
        raise ContractError(f"{track.name}: sample {i} has no valid neighbour, velocity undefined")
    return (p[b] - p[a]) / (t[b] - t[a]), scheme, [a, b]


def _velocity_at(track: PoseTrack, t: float, tol: float) -> tuple[np.ndarray, dict]:
    i0, i1, alpha, status = _locate(track, np.asarray(t, dtype=np.float64), "linear", tol)
    _raise_status(track, np.asarray(t), i0, i1, status, "linear", tol)
    i0, i1, alpha = int(i0), int(i1), float(alpha)
    v0, s0, u0 = _sample_velocity(track, i0)
    if alpha == 0.0:
        return v0, {"t": float(t), "samples": [i0], "schemes": [s0], "difference_pairs": [u0]}
    v1, s1, u1 = _sample_velocity(track, i1)
    return ((1 - alpha) * v0 + alpha * v1,
            {"t": float(t), "samples": [i0, i1], "alpha": alpha, "schemes": [s0, s1],
             "difference_pairs": [u0, u1]})


def acceleration(track: PoseTrack, t0: float, t1: float, *, tol: float = DEFAULT_TOL
                 ) -> tuple[float, dict]:
    """Magnitude of the mean acceleration ``|v(t1) - v(t0)| / (t1 - t0)`` in m/s^2.

    Estimator (also stated in the evidence): the velocity at a sample ``i`` is the central
    difference ``(p[i+1] - p[i-1]) / (t[i+1] - t[i-1])`` (forward/backward difference at a sequence
    end or next to an invalid pose); between samples it is linearly interpolated.
    """
    (t0, t1), ev = interval_valid(track, t0, t1, tol=tol)
    if t1 - t0 <= 0:
        raise ContractError(f"{track.name}: zero-length interval, acceleration undefined")
    v0, e0 = _velocity_at(track, t0, tol)
    v1, e1 = _velocity_at(track, t1, tol)
    a = (v1 - v0) / (t1 - t0)
    ev.update(track.describe())
    ev.update({"estimator": "mean acceleration (v(t1) - v(t0)) / (t1 - t0); v at a sample by central "
                            "difference (p[i+1]-p[i-1])/(t[i+1]-t[i-1]), one-sided at ends/invalid "
                            "neighbours, linear between samples",
               "v_t0": v0.tolist(), "v_t1": v1.tolist(), "velocity_t0": e0, "velocity_t1": e1,
               "vector": a.tolist(), "dt_s": t1 - t0})
    return float(np.linalg.norm(a)), ev


# ---------------------------------------------------------------------------------------------
# headings


def _unit(v: Sequence[float] | np.ndarray, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"{what} must be a non-zero finite 3-vector, got {v}")
    return v / n


def horizontal_heading_deg(R0: np.ndarray, R1: np.ndarray, forward_axis: Sequence[float] = (0, 0, 1),
                           up: Sequence[float] = (0, 0, 1), *, min_horizontal: float = 1e-6
                           ) -> np.ndarray:
    """Signed gravity-horizontal heading change (degrees, ``[-180, 180)``) from ``R0`` to ``R1``.

    The report's Eq. (heading), vectorised over ``[..., 3, 3]`` rotations ``R_world_from_entity``::

        f = R a;   h = (f - u (u.f)) / |f - u (u.f)|;   theta = atan2(u.(h0 x h1), h0.h1)

    Positive = counter-clockwise seen from ``up`` (a left turn for ``up`` pointing up). Entries
    whose forward axis is within ``min_horizontal`` of vertical are NaN.
    """
    a = _unit(forward_axis, "forward_axis")
    u = _unit(up, "up")
    f0 = np.asarray(R0, dtype=np.float64) @ a
    f1 = np.asarray(R1, dtype=np.float64) @ a
    h0 = f0 - np.einsum("...i,i->...", f0, u)[..., None] * u
    h1 = f1 - np.einsum("...i,i->...", f1, u)[..., None] * u
    n0 = np.linalg.norm(h0, axis=-1)
    n1 = np.linalg.norm(h1, axis=-1)
    degenerate = (n0 < min_horizontal) | (n1 < min_horizontal)
    with np.errstate(invalid="ignore", divide="ignore"):
        h0 = h0 / n0[..., None]
        h1 = h1 / n1[..., None]
    s = np.einsum("...i,i->...", np.cross(h0, h1), u)
    c = np.einsum("...i,...i->...", h0, h1)
    theta = wrap_deg(np.degrees(np.arctan2(s, c)))
    return np.where(degenerate, np.nan, theta)


def heading_change(track: PoseTrack, t0: float, t1: float, forward_axis: Sequence[float] = (0, 0, 1),
                   up: Sequence[float] = (0, 0, 1), *, rule: str = "linear",
                   tol: float = DEFAULT_TOL) -> tuple[float, dict]:
    """Signed gravity-horizontal heading change of ``forward_axis`` from ``t0`` to ``t1`` (degrees).

    Implements the report's Eq. (heading) (see :func:`horizontal_heading_deg`): ``forward_axis``
    is the optical/forward axis in the entity frame (OpenCV cameras ``(0, 0, 1)``, Waymo vehicle
    and boxes ``(1, 0, 0)``); ``up`` is the world-up unit vector (ScanNet raw and Waymo world
    ``(0, 0, 1)``). The result is wrapped to ``[-180, 180)``; positive is a left
    (counter-clockwise about ``up``) turn. Only the two endpoint poses are used.
    """
    (t0, t1), ev = interval_valid(track, t0, t1, tol=tol)
    T0, e0 = pose_at(track, t0, rule, tol)
    T1, e1 = pose_at(track, t1, rule, tol)
    theta = float(horizontal_heading_deg(T0[:3, :3], T1[:3, :3], forward_axis, up))
    if not np.isfinite(theta):
        raise ContractError(f"{track.name}: forward axis is vertical at an endpoint; heading undefined")
    a = _unit(forward_axis, "forward_axis")
    ev.update(track.describe())
    ev.update({"operator": "atan2(u.(h0 x h1), h0.h1), h = horizontal projection of R a",
               "forward_axis": a.tolist(), "up": _unit(up, "up").tolist(), "rule": rule,
               "indices_t0": e0["indices"], "indices_t1": e1["indices"],
               "forward_t0": (T0[:3, :3] @ a).tolist(), "forward_t1": (T1[:3, :3] @ a).tolist()})
    return theta, ev


def legacy_plane_angle(track: PoseTrack, t0: float, t1: float, column: int = 2,
                       plane: tuple[str, str] = ("x", "z"), *, rule: str = "linear",
                       tol: float = DEFAULT_TOL) -> tuple[float, dict]:
    """The legacy Orientation operator: a camera column projected on a raw-world coordinate plane.

    With ``a = R(t0)[:, column]``, ``b = R(t1)[:, column]`` and plane axes ``(i, j)``::

        angle = atan2(a_i b_j - a_j b_i, a_i b_i + a_j b_j)      (degrees, [-180, 180))

    Sign convention: positive when the projected column turns from the plane's first axis toward
    its second (for ``("x", "z")``: from +X toward +Z). For ScanNet, where raw +Z is vertical, this
    is a vertical-plane angle, not a heading; it exists to diagnose legacy labels.
    """
    i, j = _AXES[plane[0]], _AXES[plane[1]]
    (t0, t1), ev = interval_valid(track, t0, t1, tol=tol)
    T0, e0 = pose_at(track, t0, rule, tol)
    T1, e1 = pose_at(track, t1, rule, tol)
    a = T0[:3, column]
    b = T1[:3, column]
    ang = wrap_deg(np.degrees(np.arctan2(a[i] * b[j] - a[j] * b[i], a[i] * b[i] + a[j] * b[j])))
    ev.update(track.describe())
    ev.update({"operator": f"column {column} projected on world {plane[0]}-{plane[1]}, "
                           f"atan2(a_{plane[0]} b_{plane[1]} - a_{plane[1]} b_{plane[0]}, dot)",
               "indices_t0": e0["indices"], "indices_t1": e1["indices"]})
    return float(ang), ev


# ---------------------------------------------------------------------------------------------
# trajectory description


def segment_turns(track: PoseTrack, t0: float, t1: float, *, turn_threshold_deg: float = 15.0,
                  min_move_m: float = 1.0, turn_rate_deg_s: float = 3.0,
                  forward_axis: Sequence[float] = (0, 0, 1), up: Sequence[float] = (0, 0, 1),
                  rule: str = "linear", tol: float = DEFAULT_TOL
                  ) -> tuple[list[tuple[str, float]], dict]:
    """Describe the motion in ``[t0, t1]`` as "move forward" / "turn left|right" segments.

    Algorithm (all on the samples ``p(t0)``, interior source samples, ``p(t1)``):

    1. heading ``psi_k`` of ``forward_axis`` relative to the first sample (Eq. heading), unwrapped;
    2. each step ``k -> k+1`` is *turning* when ``|d psi| / dt >= turn_rate_deg_s``, with the sign
       of ``d psi`` (left = counter-clockwise about ``up``), otherwise *moving*;
    3. runs of equal step labels form segments; a moving run shorter than ``min_move_m`` between
       two turns of the same sign joins them (a pause inside one turn);
    4. a turn whose total ``|d psi|`` is below ``turn_threshold_deg`` becomes moving, adjacent
       moving runs merge, and moving runs still shorter than ``min_move_m`` are dropped (their
       distance is reported in the evidence as ``unreported_short_moves_m``).

    Returns
    -------
    segments : list of ``("move forward", metres)`` or ``("turn left"|"turn right", degrees)``;
        turn degrees are positive magnitudes. An empty list means no significant movement.
    evidence : dict with per-segment ``t_start``, ``t_end``, ``distance_m``, ``heading_change_deg``,
        the parameters, the total path length and the distance not reported (short moves and
        distance covered while turning).
    """
    ts, ps, idx, ev = _interval_samples(track, t0, t1, rule, tol, "error")
    t0u, t1u = float(ts[0]), float(ts[-1])
    T_ends, _ = pose_at(track, np.array([t0u, t1u]), rule, tol)
    Rs = np.concatenate([T_ends[:1, :3, :3], track.T[idx, :3, :3], T_ends[1:, :3, :3]], axis=0)
    psi_rel = horizontal_heading_deg(Rs[:1], Rs, forward_axis, up)
    if not np.isfinite(psi_rel).all():
        raise ContractError(f"{track.name}: forward axis vertical at some sample; headings undefined")
    psi = np.degrees(np.unwrap(np.radians(psi_rel)))
    ds = np.linalg.norm(np.diff(ps, axis=0), axis=1)
    dpsi = np.diff(psi)
    dt = np.diff(ts)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = np.where(dt > 0, dpsi / np.where(dt > 0, dt, 1.0), 0.0)
    label = np.where(np.abs(rate) >= turn_rate_deg_s, np.sign(dpsi), 0).astype(int)

    cs = np.concatenate([[0.0], np.cumsum(ds)])

    def runs_of(lab_steps: np.ndarray):
        """Maximal runs of equal step labels: (label, start, end (exclusive), distance, d psi)."""
        if lab_steps.size == 0:
            e = np.zeros(0, dtype=int)
            return e, e, e, np.zeros(0), np.zeros(0)
        cuts = np.flatnonzero(np.diff(lab_steps)) + 1
        a = np.concatenate([[0], cuts])
        b = np.concatenate([cuts, [lab_steps.size]])
        return lab_steps[a], a, b, cs[b] - cs[a], psi[b] - psi[a]

    # 3. a short pause between two turns of the same sign belongs to the turn
    lab, a, b, dist, dp = runs_of(label)
    if lab.size > 2:
        pause = (lab[1:-1] == 0) & (dist[1:-1] < min_move_m) & (lab[:-2] == lab[2:]) & (lab[:-2] != 0)
        lab = lab.copy()
        lab[1:-1][pause] = lab[:-2][pause]
        label = np.repeat(lab, b - a)
    # 4. small turns are moves; short moves are dropped and their neighbours merge
    lab, a, b, dist, dp = runs_of(label)
    lab = np.where((lab != 0) & (np.abs(dp) < turn_threshold_deg), 0, lab)
    lab, a, b, dist, dp = runs_of(np.repeat(lab, b - a))
    short = (lab == 0) & (dist < min_move_m)
    dropped = float(dist[short].sum())
    lab, a, b, dist, dp = lab[~short], a[~short], b[~short], dist[~short], dp[~short]
    if lab.size:
        first = np.concatenate([[0], np.flatnonzero(np.diff(lab)) + 1])
        last = np.concatenate([first[1:] - 1, [lab.size - 1]])
        runs = zip(lab[first], a[first], b[last], np.add.reduceat(dist, first), np.add.reduceat(dp, first))
    else:
        runs = iter(())

    segments: list[tuple[str, float]] = []
    details = []
    turning_distance = 0.0
    for lab_k, a_k, b_k, dist_k, dp_k in runs:
        dist_k, dp_k = float(dist_k), float(dp_k)
        if lab_k == 0:
            segments.append(("move forward", dist_k))
        else:
            segments.append(("turn left" if dp_k > 0 else "turn right", abs(dp_k)))
            turning_distance += dist_k
        details.append({"kind": segments[-1][0], "t_start": float(ts[a_k]), "t_end": float(ts[b_k]),
                        "distance_m": dist_k, "heading_change_deg": dp_k})
    ev.update(track.describe())
    ev.update({"segments": details, "path_length_m": float(ds.sum()),
               "unreported_short_moves_m": dropped, "distance_while_turning_m": turning_distance,
               "params": {"turn_threshold_deg": turn_threshold_deg, "min_move_m": min_move_m,
                          "turn_rate_deg_s": turn_rate_deg_s,
                          "forward_axis": _unit(forward_axis, "forward_axis").tolist(),
                          "up": _unit(up, "up").tolist()}})
    if not segments:
        ev["summary"] = "no significant movement"
    return segments, ev
