"""Geometry: rigid transforms and axis conventions (:mod:`.frames`), oriented boxes (:mod:`.boxes`),
pose tracks and trajectory operators (:mod:`.trajectory`)."""

from resti_lib.geometry.boxes import OrientedBox, upright_oriented_box  # noqa: F401
from resti_lib.geometry.frames import (  # noqa: F401
    R_CV_FROM_WAYMO,
    R_WAYMO_FROM_CV,
    T_CV_CAM_FROM_WAYMO_CAM,
    T_WAYMO_CAM_FROM_CV_CAM,
    apply_T,
    check_rotation,
    invert_T,
    make_T,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
    yaw_matrix,
)
from resti_lib.geometry.trajectory import PoseTrack, pose_at  # noqa: F401
