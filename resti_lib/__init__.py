"""resti: audit and repair spatial-temporal video benchmarks against their source data.

The tasks are the task registry's (:func:`resti_lib.tasks.names`); the constants here are the
benchmark's sources, answer letters and scene types.

Pipeline stages, one module (or sub-package) each:
contract -> sources -> reconstruct (tasks) -> adjudicate -> options/attacks -> release/report.
"""

__version__ = "0.1.0"

SOURCES = ("ScanNet", "Waymo", "Omni6DPose")
LETTERS = ("A", "B", "C", "D", "E")
SCENE_OF_SOURCE = {"ScanNet": "indoor", "Waymo": "outdoor", "Omni6DPose": "desktop"}
