"""Waymo Open Dataset v2 (Perception) parquet readers.

Layout: ``<root>/<component>/<segment_context_name>.parquet`` (``../shared/formats/waymo_v2.md``).
Only the needed columns are read (pyarrow column projection); camera image bytes are never read.

Frames and conventions
----------------------
- Vehicle and Waymo camera frames: +X forward, +Y left, +Z up. World: the segment's ENU-like frame.
- ``world_from_vehicle(t)``: ``[VehiclePoseComponent].world_from_vehicle.transform`` (row-major).
- ``extrinsic(camera) = T_vehicle_from_waymo_cam``.
- Camera tracks are returned in OpenCV camera axes:
  ``T_world_from_cam = world_from_vehicle(t) @ extrinsic(camera) @ T_WAYMO_CAM_FROM_CV_CAM``.
- LiDAR boxes are in the vehicle frame of their own frame timestamp; ``heading`` is the yaw about
  vehicle +Z; ``size = (length along heading, width, height)``. World box pose:
  ``T_world_from_box = world_from_vehicle(frame) @ [yaw(heading) | center]``.
- Segment time ``t = (micros - first_micros) / 1e6`` with ``first_micros`` the first
  ``vehicle_pose`` frame of the segment.
- ``key.camera_name`` is the CameraName enum, stored as an integer (int8) in some components and as
  its name (``FRONT``, ``FRONT_LEFT`` ...; the official ``camera_hkp`` test file) in others: every
  reader accepts both (:func:`camera_numbers`).
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from resti_lib.errors import InputError, SourceError
from resti_lib.geometry.frames import T_WAYMO_CAM_FROM_CV_CAM, check_rotation, make_T, yaw_matrix
from resti_lib.geometry.trajectory import PoseTrack

__all__ = [
    "BOX_TYPES",
    "CAL_EXTRINSIC",
    "CAMERA_NAMES",
    "IMG_POSE",
    "IMG_POSE_TIMESTAMP",
    "KEY_CAMERA",
    "KEY_MICROS",
    "KEY_OBJECT",
    "KEY_SEGMENT",
    "VEHICLE_POSE",
    "WaymoSegment",
    "camera_number",
    "camera_numbers",
    "read_camera_calibration",
    "read_camera_image_poses",
    "read_camera_numbers",
    "read_columns",
    "read_lidar_boxes",
    "read_vehicle_pose",
]

CAMERA_NAMES = {1: "FRONT", 2: "FRONT_LEFT", 3: "FRONT_RIGHT", 4: "SIDE_LEFT", 5: "SIDE_RIGHT"}
BOX_TYPES = {0: "TYPE_UNKNOWN", 1: "TYPE_VEHICLE", 2: "TYPE_PEDESTRIAN", 3: "TYPE_SIGN", 4: "TYPE_CYCLIST"}

KEY_SEGMENT = "key.segment_context_name"
KEY_MICROS = "key.frame_timestamp_micros"
KEY_CAMERA = "key.camera_name"
KEY_OBJECT = "key.laser_object_id"
VEHICLE_POSE = "[VehiclePoseComponent].world_from_vehicle.transform"
_CAL = "[CameraCalibrationComponent]"
CAL_EXTRINSIC = f"{_CAL}.extrinsic.transform"
CAL_INTRINSIC = {k: f"{_CAL}.intrinsic.{k}" for k in ("f_u", "f_v", "c_u", "c_v", "k1", "k2", "p1", "p2", "k3")}
CAL_WIDTH = f"{_CAL}.width"
CAL_HEIGHT = f"{_CAL}.height"
IMG_POSE = "[CameraImageComponent].pose.transform"
IMG_POSE_TIMESTAMP = "[CameraImageComponent].pose_timestamp"
_BOX = "[LiDARBoxComponent]"
BOX_COLUMNS = {
    "cx": f"{_BOX}.box.center.x", "cy": f"{_BOX}.box.center.y", "cz": f"{_BOX}.box.center.z",
    "length": f"{_BOX}.box.size.x", "width": f"{_BOX}.box.size.y", "height": f"{_BOX}.box.size.z",
    "heading": f"{_BOX}.box.heading", "type": f"{_BOX}.type",
}
#: optional in the v2 schema (``Optional[Vec3d]``): absent columns read as NaN
BOX_OPTIONAL = {
    "speed_x": f"{_BOX}.speed.x", "speed_y": f"{_BOX}.speed.y", "speed_z": f"{_BOX}.speed.z",
    "accel_x": f"{_BOX}.acceleration.x", "accel_y": f"{_BOX}.acceleration.y",
    "accel_z": f"{_BOX}.acceleration.z",
}
ROTATION_TOL = 1e-4  # transforms may be stored as float32


def camera_number(camera: int | str) -> int:
    """CameraName enum value (1..5) from an int, a digit string or a name (``FRONT``, ``front_left``)."""
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool):
        n = int(camera)
    else:
        s = str(camera).strip().upper()
        if s.isdigit():
            n = int(s)
        else:
            names = {v: k for k, v in CAMERA_NAMES.items()}
            if s not in names:
                raise InputError(f"unknown Waymo camera {camera!r} (1-5 or {', '.join(CAMERA_NAMES.values())})",
                                 field="camera")
            n = names[s]
    if n not in CAMERA_NAMES:
        raise InputError(f"unknown Waymo camera number {n} (1-5)", field="camera")
    return n


def camera_numbers(table: pa.Table, path: str | Path, column: str = KEY_CAMERA) -> np.ndarray:
    """The camera column as CameraName numbers (1..5) ``[N]`` int64, stored as integers or as names.

    Integer columns (int8 in the v2 schema) must hold 1..5; text columns the names ``FRONT``,
    ``FRONT_LEFT``, ``FRONT_RIGHT``, ``SIDE_LEFT``, ``SIDE_RIGHT`` (any case; digit strings also).

    Raises
    ------
    InputError
        Naming the file, the first bad row and the column: a null, a number or name that is no
        camera, or a column of another type.
    """
    arr = table.column(column).combine_chunks()
    if pa.types.is_dictionary(arr.type):
        arr = arr.cast(arr.type.value_type)
    if arr.null_count:
        i = int(np.flatnonzero(np.asarray(arr.is_null().to_numpy(zero_copy_only=False)))[0])
        raise SourceError("camera name is missing (null)", file=path, row=i, field=column)
    if pa.types.is_integer(arr.type):
        out = np.asarray(arr.to_numpy(zero_copy_only=False)).astype(np.int64)
        bad = ~np.isin(out, list(CAMERA_NAMES))
        if bad.any():
            i = int(np.argmax(bad))
            raise SourceError(f"camera name {int(out[i])} is not a camera (1-5: "
                             f"{', '.join(CAMERA_NAMES.values())})", file=path, row=i, field=column)
        return out
    if pa.types.is_string(arr.type) or pa.types.is_large_string(arr.type):
        vals = np.asarray(arr.to_numpy(zero_copy_only=False)).astype(str)
        uniq, inv = np.unique(vals, return_inverse=True)
        names = {v: k for k, v in CAMERA_NAMES.items()}
        nums = []
        for j, u in enumerate(uniq.tolist()):
            key = u.strip().upper()
            n = int(key) if key.isdigit() else names.get(key)
            if n not in CAMERA_NAMES:
                i = int(np.argmax(inv == j))
                raise SourceError(f"camera name {u!r} is not a camera ({', '.join(CAMERA_NAMES.values())} or 1-5)",
                                 file=path, row=i, field=column)
            nums.append(n)
        return np.asarray(nums, dtype=np.int64)[inv.reshape(-1)]
    raise SourceError(f"camera name column has type {arr.type}: expected an integer (int8) or a name (string)",
                     file=path, field=column)


def read_columns(path: str | Path, required: list[str], optional: list[str] = ()) -> pa.Table:
    """Read only ``required`` (+ present ``optional``) columns; InputError naming a missing one."""
    path = Path(path)
    if not path.exists():
        raise SourceError("parquet file not found", file=path)
    try:
        names = set(pq.read_schema(path).names)
    except (pa.ArrowException, OSError) as e:  # not a parquet file
        raise SourceError(f"not a readable parquet file: {e}", file=path) from None
    for c in required:
        if c not in names:
            raise SourceError("missing column", file=path, field=c)
    cols = list(required) + [c for c in optional if c in names]
    return pq.read_table(path, columns=cols)


def _transforms(table: pa.Table, column: str, path: Path) -> np.ndarray:
    """``[N, 4, 4]`` float64 from a 16-float list column (row-major); null rows become NaN."""
    arr = table.column(column).combine_chunks()
    n = len(arr)
    if not (pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type)
            or pa.types.is_large_list(arr.type)):
        raise SourceError(f"expected a list of 16 numbers, got {arr.type}", file=path, field=column)
    out = np.full((n, 16), np.nan)
    if pa.types.is_fixed_size_list(arr.type):
        if arr.type.list_size != 16:
            raise SourceError(f"expected 16 numbers per row, got {arr.type.list_size}", file=path, field=column)
        vals = np.asarray(arr.values.to_numpy(zero_copy_only=False), dtype=np.float64).reshape(n, 16)
        ok = ~np.asarray(arr.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        out[ok] = vals[ok]
    else:
        lens = np.asarray(arr.value_lengths().fill_null(16).to_numpy(zero_copy_only=False))
        if (lens != 16).any():
            i = int(np.argmax(lens != 16))
            raise SourceError(f"expected 16 numbers, got {lens[i]}", file=path, row=i, field=column)
        ok = ~np.asarray(arr.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        flat = np.asarray(arr.flatten().to_numpy(zero_copy_only=False), dtype=np.float64)
        out[ok] = flat.reshape(-1, 16)
    return out.reshape(n, 4, 4)


def _segment_rows(table: pa.Table, segment: str | None, path: Path) -> np.ndarray:
    names = np.asarray(table.column(KEY_SEGMENT).to_numpy(zero_copy_only=False)).astype(str)
    if segment is None:
        return np.ones(len(names), bool)
    keep = names == segment
    if not keep.any():
        raise SourceError(f"no row of segment {segment!r}", file=path, field=KEY_SEGMENT)
    return keep


def _int_col(table: pa.Table, column: str) -> np.ndarray:
    return np.asarray(table.column(column).to_numpy(zero_copy_only=False))


def read_vehicle_pose(path: str | Path, segment: str | None = None, *, rotation_tol: float = ROTATION_TOL
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``vehicle_pose`` component -> ``(micros [N] int64, world_from_vehicle [N, 4, 4])`` sorted by time.

    Raises
    ------
    InputError
        Missing column, duplicate timestamps, or a finite transform that is not rigid.
    """
    path = Path(path)
    tab = read_columns(path, [KEY_SEGMENT, KEY_MICROS, VEHICLE_POSE])
    keep = _segment_rows(tab, segment, path)
    micros = _int_col(tab, KEY_MICROS).astype(np.int64)[keep]
    T = _transforms(tab, VEHICLE_POSE, path)[keep]
    back = np.flatnonzero(np.diff(micros) <= 0)
    if back.size:  # a pose table runs forward in time: a reversed or repeated timestamp is damage
        k = int(back[0]) + 1
        raise SourceError(f"frame timestamp {micros[k]} does not follow {micros[k - 1]} (the pose table must be "
                          "strictly increasing in time)", file=path, row=int(np.flatnonzero(keep)[k]), field=KEY_MICROS)
    order = np.argsort(micros, kind="stable")
    micros, T = micros[order], T[order]
    file_rows = np.flatnonzero(keep)[order]  # row in the file of each sorted frame
    dup = np.flatnonzero(np.diff(micros) == 0)
    if dup.size:
        raise SourceError(f"duplicate frame timestamp {micros[dup[0]]}", file=path, row=int(file_rows[dup[0] + 1]),
                         field=KEY_MICROS)
    fin = np.isfinite(T).all(axis=(1, 2))
    if fin.any():
        idx = np.flatnonzero(fin)
        try:
            check_rotation(T[fin, :3, :3], tol=rotation_tol, field=VEHICLE_POSE)
        except InputError as e:
            raise SourceError(e.message, file=path, row=int(file_rows[idx[e.row]]), field=VEHICLE_POSE) from None
    return micros, T


def read_camera_calibration(path: str | Path, segment: str | None = None) -> dict[int, dict]:
    """``camera_calibration`` -> ``{camera_number: {"extrinsic", "intrinsics", "width", "height"}}``.

    ``extrinsic`` is ``T_vehicle_from_waymo_cam`` (4x4, Waymo camera axes); ``intrinsics`` holds
    ``f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3`` (pixels / unitless, OpenCV distortion model).
    """
    path = Path(path)
    req = [KEY_SEGMENT, KEY_CAMERA, CAL_EXTRINSIC, *CAL_INTRINSIC.values(), CAL_WIDTH, CAL_HEIGHT]
    tab = read_columns(path, req)
    keep = _segment_rows(tab, segment, path)
    cams = camera_numbers(tab, path)
    E = _transforms(tab, CAL_EXTRINSIC, path)
    out: dict[int, dict] = {}
    cols = {k: np.asarray(tab.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)
            for k, c in CAL_INTRINSIC.items()}
    W = _int_col(tab, CAL_WIDTH)
    H = _int_col(tab, CAL_HEIGHT)
    for i in np.flatnonzero(keep):
        cam = int(cams[i])
        if cam in out:
            raise SourceError(f"camera {cam} calibrated twice", file=path, row=int(i), field=KEY_CAMERA)
        if not np.isfinite(E[i]).all():
            raise SourceError("non-finite extrinsic", file=path, row=int(i), field=CAL_EXTRINSIC)
        check_rotation(E[i, :3, :3], tol=ROTATION_TOL, file=path, row=int(i), field=CAL_EXTRINSIC)
        out[cam] = {"extrinsic": E[i], "intrinsics": {k: float(v[i]) for k, v in cols.items()},
                    "width": int(W[i]), "height": int(H[i]), "row": int(i)}
    return out


def read_camera_image_poses(path: str | Path, camera: int | str, segment: str | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-image vehicle poses of one camera from ``camera_image`` (the JPEG column is not read).

    Returns
    -------
    frame_micros : int64 ``[N]``; pose_timestamp : float64 ``[N]`` (seconds, epoch);
    world_from_vehicle : ``[N, 4, 4]`` at ``pose_timestamp``. Sorted by ``pose_timestamp``.
    """
    path = Path(path)
    cam = camera_number(camera)
    tab = read_columns(path, [KEY_SEGMENT, KEY_MICROS, KEY_CAMERA, IMG_POSE, IMG_POSE_TIMESTAMP])
    keep = _segment_rows(tab, segment, path) & (camera_numbers(tab, path) == cam)
    if not keep.any():
        raise SourceError(f"no image rows for camera {cam}", file=path, field=KEY_CAMERA)
    micros = _int_col(tab, KEY_MICROS).astype(np.int64)[keep]
    ts = np.asarray(tab.column(IMG_POSE_TIMESTAMP).to_numpy(zero_copy_only=False), dtype=np.float64)[keep]
    T = _transforms(tab, IMG_POSE, path)[keep]
    order = np.argsort(ts, kind="stable")
    return micros[order], ts[order], T[order]


def read_camera_numbers(path: str | Path, segment: str | None = None) -> np.ndarray:
    """The ``key.camera_name`` column of any camera component (``camera_image``, ``camera_calibration``,
    ``camera_box``, ``camera_hkp`` ...) as CameraName numbers ``[N]`` (rows of ``segment`` when given);
    names for them: :data:`CAMERA_NAMES`."""
    path = Path(path)
    tab = read_columns(path, [KEY_SEGMENT, KEY_CAMERA])
    keep = _segment_rows(tab, segment, path)
    return camera_numbers(tab, path)[keep]


def read_lidar_boxes(path: str | Path, segment: str | None = None):
    """``lidar_box`` -> pandas DataFrame, one row per (frame, object), sorted by (id, micros).

    Columns: ``micros``, ``id`` (laser_object_id), ``type`` (int), ``type_name``, ``cx, cy, cz``,
    ``length, width, height`` (metres), ``heading`` (rad, vehicle frame), ``speed_x/y/z`` (m/s),
    ``accel_x/y/z`` (m/s^2) -- vehicle-frame quantities as stored; optional ones NaN when absent.
    """
    import pandas as pd

    path = Path(path)
    tab = read_columns(path, [KEY_SEGMENT, KEY_MICROS, KEY_OBJECT, *BOX_COLUMNS.values()],
                       list(BOX_OPTIONAL.values()))
    keep = _segment_rows(tab, segment, path)
    data = {"micros": _int_col(tab, KEY_MICROS).astype(np.int64),
            "id": np.asarray(tab.column(KEY_OBJECT).to_numpy(zero_copy_only=False)).astype(str)}
    for k, c in {**BOX_COLUMNS, **BOX_OPTIONAL}.items():
        if c in tab.column_names:
            data[k] = np.asarray(tab.column(c).to_numpy(zero_copy_only=False), dtype=np.float64)
        else:
            data[k] = np.full(len(tab), np.nan)
    df = pd.DataFrame(data)[keep]
    df["type"] = df["type"].astype(int)
    df["type_name"] = df["type"].map(BOX_TYPES).fillna("TYPE_UNKNOWN")
    df["source_row"] = np.flatnonzero(keep)
    dup = df.duplicated(["id", "micros"])
    if dup.any():
        r = df[dup].iloc[0]
        raise SourceError(f"object {r['id']} twice at {r['micros']}", file=path, row=int(r["source_row"]),
                          field=KEY_OBJECT)
    # each track runs forward in time in the file (rows of one object, in file order)
    prev = df.groupby("id", sort=False)["micros"].shift()
    back = df.index[(df["micros"] <= prev).to_numpy()]
    if len(back):
        r = df.loc[back[0]]
        raise SourceError(f"object {r['id']}: frame timestamp {r['micros']} does not follow the track's previous "
                          "one (a track must be strictly increasing in time)", file=path, row=int(r["source_row"]),
                          field=KEY_MICROS)
    return df.sort_values(["id", "micros"], kind="stable").reset_index(drop=True)


class WaymoSegment:
    """One Waymo v2 segment under ``root`` (``<root>/<component>/<segment>.parquet``).

    Parameters
    ----------
    root : path
        The folder holding the component folders.
    segment : str
        ``segment_context_name``.
    """

    def __init__(self, root: str | Path, segment: str):
        self.root = Path(root)
        self.segment = segment

    def path(self, component: str) -> Path:
        return self.root / component / f"{self.segment}.parquet"

    # -- vehicle poses and time
    @cached_property
    def _vehicle(self) -> tuple[np.ndarray, np.ndarray]:
        return read_vehicle_pose(self.path("vehicle_pose"), self.segment)

    @property
    def first_micros(self) -> int:
        """Timestamp (µs) of the segment's first vehicle_pose frame: ``t = 0``."""
        return int(self._vehicle[0][0])

    def time_of_micros(self, micros: np.ndarray | int) -> np.ndarray | float:
        """Segment time in seconds: ``(micros - first_micros) / 1e6``."""
        t = (np.asarray(micros, dtype=np.int64) - self.first_micros) / 1e6
        return float(t) if np.ndim(t) == 0 else t

    @property
    def duration(self) -> float:
        m = self._vehicle[0]
        return (int(m[-1]) - int(m[0])) / 1e6

    def ego_track(self) -> PoseTrack:
        """``world_from_vehicle`` track (vehicle axes: +X forward, +Z up; origin rear-axle centre)."""
        micros, T = self._vehicle
        return PoseTrack(self.time_of_micros(micros), T, name=f"{self.segment} vehicle",
                         source=str(self.path("vehicle_pose")),
                         meta={"micros": micros, "axes": "vehicle (+X forward, +Y left, +Z up)"})

    # -- cameras
    @cached_property
    def calibration(self) -> dict[int, dict]:
        """``{camera_number: {...}}`` from ``camera_calibration`` (see :func:`read_camera_calibration`)."""
        return read_camera_calibration(self.path("camera_calibration"), self.segment)

    def camera_calibration(self, camera: int | str) -> dict:
        cam = camera_number(camera)
        if cam not in self.calibration:
            raise InputError(f"camera {cam} ({CAMERA_NAMES[cam]}) not calibrated",
                             file=self.path("camera_calibration"), field=KEY_CAMERA)
        return self.calibration[cam]

    def camera_track(self, camera: int | str, *, poses: str = "vehicle_pose") -> PoseTrack:
        """Camera track ``T_world_from_cam`` in OpenCV camera axes.

        ``T = world_from_vehicle(t) @ extrinsic(camera) @ T_WAYMO_CAM_FROM_CV_CAM``.

        Parameters
        ----------
        poses : {"vehicle_pose", "camera_image"}
            ``vehicle_pose``: the frame poses (top-lidar mid-spin) at frame times.
            ``camera_image``: each image's own pose at its ``pose_timestamp``.
        """
        cam = camera_number(camera)
        E = self.camera_calibration(cam)["extrinsic"]
        chain = E @ T_WAYMO_CAM_FROM_CV_CAM
        name = f"{self.segment} camera {cam} ({CAMERA_NAMES[cam]})"
        if poses == "vehicle_pose":
            micros, W = self._vehicle
            return PoseTrack(self.time_of_micros(micros), W @ chain, name=name,
                             source=f"{self.path('vehicle_pose')} + {self.path('camera_calibration')}",
                             meta={"micros": micros, "camera": cam, "chain": "world_from_vehicle @ "
                                   "extrinsic @ T_waymo_cam_from_cv_cam", "axes": "OpenCV"})
        if poses == "camera_image":
            micros, ts, W = read_camera_image_poses(self.path("camera_image"), cam, self.segment)
            t = ts - self.first_micros / 1e6
            return PoseTrack(t, W @ chain, name=name + " image poses",
                             source=f"{self.path('camera_image')} + {self.path('camera_calibration')}",
                             meta={"frame_micros": micros, "pose_timestamp": ts, "camera": cam,
                                   "axes": "OpenCV"})
        raise ValueError(f"poses must be 'vehicle_pose' or 'camera_image', got {poses!r}")

    # -- boxes
    @cached_property
    def lidar_boxes(self):
        """All LiDAR boxes (DataFrame, see :func:`read_lidar_boxes`) with segment time ``t``."""
        df = read_lidar_boxes(self.path("lidar_box"), self.segment)
        df["t"] = self.time_of_micros(df["micros"].to_numpy())
        return df

    def _world_from_vehicle_at_micros(self, micros: np.ndarray, rows: np.ndarray) -> np.ndarray:
        vm, W = self._vehicle
        k = np.searchsorted(vm, micros)
        kc = np.clip(k, 0, len(vm) - 1)
        miss = vm[kc] != micros
        if miss.any():
            i = int(np.argmax(miss))
            raise SourceError(f"box frame {int(micros[i])} has no vehicle_pose frame",
                             file=self.path("lidar_box"), row=int(rows[i]), field=KEY_MICROS)
        return W[kc]

    def _box_world(self, df) -> np.ndarray:
        W = self._world_from_vehicle_at_micros(df["micros"].to_numpy(), df["source_row"].to_numpy())
        T_vb = make_T(yaw_matrix(df["heading"].to_numpy()), df[["cx", "cy", "cz"]].to_numpy())
        return W @ T_vb

    def object_track(self, laser_object_id: str) -> PoseTrack:
        """World box poses ``T_world_from_box`` of one tracked object (box +X along its heading).

        ``meta`` carries per-sample ``size`` ``[N, 3]`` (length, width, height), ``type``, and the
        stored vehicle-frame ``speed`` and ``accel`` vectors.
        """
        df = self.lidar_boxes
        sel = df[df["id"] == str(laser_object_id)]
        if sel.empty:
            raise InputError(f"no box with laser_object_id {laser_object_id!r}", file=self.path("lidar_box"),
                             field=KEY_OBJECT)
        T = self._box_world(sel)
        return PoseTrack(sel["t"].to_numpy(), T, name=f"{self.segment} object {laser_object_id}",
                         source=f"{self.path('lidar_box')} + {self.path('vehicle_pose')}",
                         meta={"micros": sel["micros"].to_numpy(),
                               "size": sel[["length", "width", "height"]].to_numpy(),
                               "type": sel["type_name"].iloc[0],
                               "speed": sel[["speed_x", "speed_y", "speed_z"]].to_numpy(),
                               "accel": sel[["accel_x", "accel_y", "accel_z"]].to_numpy()})

    @cached_property
    def box_frame_times(self) -> np.ndarray:
        """Sorted segment times (s) of the frames that carry LiDAR boxes (empty when none)."""
        return np.unique(self.lidar_boxes["t"].to_numpy())

    def nearest_box_frame(self, t: float) -> float | None:
        """Segment time of the box frame nearest ``t``; None when the segment has no box."""
        frames = self.box_frame_times
        if frames.size == 0:
            return None
        return float(frames[int(np.argmin(np.abs(frames - t)))])

    def boxes_at(self, t: float, *, tol: float = 1e-3) -> list[dict]:
        """Boxes of the frame at segment time ``t`` (the nearest frame within ``tol`` seconds).

        Each dict: ``id``, ``type``, ``t``, ``micros``, ``center_vehicle``, ``heading_vehicle``
        (rad), ``size`` (length, width, height), ``T_world_from_box``, ``center_world``,
        ``heading_world`` (rad, yaw of box +X in the world), ``speed``/``accel`` (vehicle frame).
        """
        return [self._box_dict(i) for i in self._frame_rows(t, tol)]

    def box_at(self, t: float, laser_object_id: str, *, tol: float = 1e-3) -> dict | None:
        """The box of one object in the frame at segment time ``t`` (as :meth:`boxes_at`), None when
        the frame has no box of that object."""
        rows = self._frame_rows(t, tol)
        if rows.size == 0:
            return None
        hit = rows[self._box_arrays["id"][rows] == str(laser_object_id)]
        return self._box_dict(int(hit[-1])) if hit.size else None  # the last, as a dict by id keeps it

    def _frame_rows(self, t: float, tol: float) -> np.ndarray:
        """Box-table rows of the frame nearest ``t`` (file order); none when the segment has no box,
        an InputError when that frame is more than ``tol`` seconds away."""
        t_frame = self.nearest_box_frame(t)
        if t_frame is None:
            return np.zeros(0, dtype=np.int64)
        if abs(t_frame - t) > tol:
            raise InputError(f"no box frame within {tol} s of t={t} (nearest {t_frame:.6f} s)",
                             file=self.path("lidar_box"), field=KEY_MICROS)
        a = self._box_arrays
        k = int(np.searchsorted(self.box_frame_times, t_frame))
        return a["order"][a["starts"][k]:a["starts"][k + 1]]

    def _box_dict(self, i: int) -> dict:
        a = self._box_arrays
        T = a["T"][i].copy()
        return {"id": a["id"][i], "type": a["type"][i], "t": float(a["t"][i]), "micros": int(a["micros"][i]),
                "center_vehicle": a["center"][i].copy(), "heading_vehicle": float(a["heading"][i]),
                "size": a["size"][i].copy(), "T_world_from_box": T, "center_world": T[:3, 3].copy(),
                "heading_world": float(np.arctan2(T[1, 0], T[0, 0])),
                "speed": a["speed"][i].copy(), "accel": a["accel"][i].copy()}

    @cached_property
    def _box_arrays(self) -> dict:
        """The box table as arrays, world poses included, with its rows grouped by frame (in file
        order within a frame): computed once per segment, so a frame's boxes cost no table scan."""
        df = self.lidar_boxes
        t = df["t"].to_numpy()
        order = np.argsort(t, kind="stable")
        starts = np.searchsorted(t[order], self.box_frame_times, side="left")
        return {"order": order, "starts": np.append(starts, t.size), "t": t, "T": self._box_world(df),
                "id": df["id"].to_numpy(), "type": df["type_name"].to_numpy(), "micros": df["micros"].to_numpy(),
                "center": df[["cx", "cy", "cz"]].to_numpy(), "heading": df["heading"].to_numpy(),
                "size": df[["length", "width", "height"]].to_numpy(),
                "speed": df[["speed_x", "speed_y", "speed_z"]].to_numpy(),
                "accel": df[["accel_x", "accel_y", "accel_z"]].to_numpy()}
