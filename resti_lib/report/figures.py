"""The registry the report page follows: order, section and caption of every figure.

The report's own figures are listed here; each registered task declares its own
(:attr:`resti_lib.tasks.base.Task.figures`), shown in the "Tasks" section in task order. A figure
that matches no entry is shown last under its file name, and a test checks that the default run
makes none.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path

from ..io.figures import FigureSpec

_ATTACKS = ("accuracy of every option-only (blind) attack per task, pooled over sources, with 95% "
            "Clopper–Pearson intervals; dashed: chance 1/5; red: Holm-significant over the whole table; "
            "an attack that abstains on some rows shows its coverage.")

FIGURES: tuple[FigureSpec, ...] = (
    FigureSpec("99_audit_overview", "Overview",
               "Audit overview. (a) Accepted and excluded questions per task, with counts; accepted = "
               "retained + corrected + re-contracted. (b) Defect reports in the report's six "
               "construction-defect categories; shares of the sum of reports (one question can report "
               "several)."),
    FigureSpec("00_answer_interface_attacks_resti_v5", "Answer interface",
               "Reference release (ReSTI v5, real data), answer-interface audit: " + _ATTACKS),
    FigureSpec("00_answer_interface_attacks_*", "Answer interface",
               "Answer-interface audit of the release named in params/answer_interface.yaml: " + _ATTACKS),
    FigureSpec("99_attacks_after", "Answer interface",
               "Our release, after repair (the options it ships): " + _ATTACKS),
    FigureSpec("99_attacks_before", "Answer interface",
               "The legacy benchmark, before repair (a hit is the keyed letter): " + _ATTACKS),
    FigureSpec("90_reoption_release_*", "Answer interface",
               "Re-optioned reference release: the strongest attack and the learned attacker per task "
               "and source, input beside output."),
    FigureSpec("01_grounding_topdown", "Tasks",
               "3D Video Grounding, one row seen from above: source boxes, the camera at the asked frame, "
               "the legacy centre mapped back into the scene and the corrected centre; the dashed line "
               "joins the legacy centre to the target (3D length)."),
    FigureSpec("01_grounding_distances", "Tasks",
               "3D Video Grounding: distance of the legacy centre to the nearest source object and of the "
               "corrected centre to its target, per source (log scale; bars: medians)."),
    FigureSpec("02_orientation_endpoints", "Tasks",
               "Ego-Centric Orientation, one row: (a) the camera column the legacy operator uses, on the "
               "vertical X–Z plane; (b) optical forward on the gravity-horizontal plane, the repaired "
               "heading change. Blue: start; gold: end."),
    FigureSpec("02_orientation_legacy_vs_operators", "Tasks",
               "Ego-Centric Orientation: the legacy value against the X–Z operator (left) and against the "
               "repaired gravity-horizontal heading (right)."),
    FigureSpec("03_dimensional_legacy_vs_source", "Tasks",
               "Dimensional Measurement: legacy against source value per source (accepted rows; dashed: "
               "equal)."),
    FigureSpec("04_relation_margins", "Tasks",
               "Spatial Relation, Omni6DPose pairs: lateral against depth offset; grey: no direction "
               "dominates by the ratio (excluded)."),
    FigureSpec("05_displacement_legacy_vs_source", "Tasks",
               "Displacement & Path Length: legacy against source value per source (accepted rows; dashed: "
               "equal)."),
    FigureSpec("06_speed_statistics", "Tasks",
               "Speed & Acceleration: the legacy 'speed' against displacement/Δt (circles) and path/Δt "
               "(triangles), per source: which statistic the legacy values are."),
    FigureSpec("06_speed_legacy_vs_source", "Tasks",
               "Speed & Acceleration: legacy against source value under the clarified contract."),
    FigureSpec("07_trajectory_paths", "Tasks",
               "Trajectory Description: top-down camera paths of distinct Waymo segments with the turn "
               "windows and the samples that split the moves."),
    FigureSpec("08_pose_translation_change", "Tasks",
               "Pose Estimation: translation change between each wrong-timestamp legacy matrix and the "
               "source pose at the asked time (Waymo)."),
)


def spec_for(stem: str) -> FigureSpec | None:
    """The first registry entry whose pattern matches ``stem``."""
    for spec in FIGURES:
        if fnmatch.fnmatchcase(stem, spec.pattern):
            return spec
    return None


def ordered_figures(fig_dir: Path) -> list[tuple[Path, FigureSpec | None]]:
    """The PNGs of ``fig_dir`` in registry order (then unregistered ones by name)."""
    pngs = sorted(Path(fig_dir).glob("*.png")) if Path(fig_dir).exists() else []
    rank = {spec.pattern: i for i, spec in enumerate(FIGURES)}

    def key(p: Path):
        spec = spec_for(p.stem)
        return (rank[spec.pattern] if spec else len(FIGURES), p.name)

    return [(p, spec_for(p.stem)) for p in sorted(pngs, key=key)]
