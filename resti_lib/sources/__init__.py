"""Exact readers of the source datasets (ScanNet, Waymo v2, Omni6DPose ROPE) and the video-name map.

Sub-modules are imported on demand (``from resti_lib.sources import scannet``) so that a reader's
heavy dependencies (trimesh, cutoop) load only when needed.
"""
