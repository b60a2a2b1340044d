"""resti: audit and repair spatial-temporal video benchmarks against their source data.

Pipeline stages, one module (or sub-package) each:
contract -> sources -> reconstruct (tasks) -> adjudicate -> options/attacks -> release/report.
"""

__version__ = "0.1.0"

TASKS = (
    "3D Video Grounding",
    "Dimensional Measurement",
    "Spatial Relation",
    "Displacement & Path Length",
    "Speed & Acceleration",
    "Ego-Centric Orientation",
    "Trajectory Description",
    "Pose Estimation",
)
SOURCES = ("ScanNet", "Waymo", "Omni6DPose")
LETTERS = ("A", "B", "C", "D", "E")
SCENE_OF_SOURCE = {"ScanNet": "indoor", "Waymo": "outdoor", "Omni6DPose": "desktop"}
