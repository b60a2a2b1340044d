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

#: The report's own figures, in page order (each task's follow, from the task registry).
REPORT_FIGURES: tuple[FigureSpec, ...] = (
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
)


def figure_specs() -> tuple[FigureSpec, ...]:
    """Every figure the report shows, in page order: the report's own, then each registered task's
    (:attr:`resti_lib.tasks.base.Task.figures`, in notebook order, section "Tasks")."""
    from ..tasks import all_tasks

    tasks = sorted(all_tasks(), key=lambda t: t.notebook)
    return REPORT_FIGURES + tuple(FigureSpec(f"{t.notebook}_{suffix}", "Tasks", caption)
                                  for t in tasks for suffix, caption in t.figures.items())


def spec_for(stem: str) -> FigureSpec | None:
    """The first registry entry whose pattern matches ``stem``."""
    for spec in figure_specs():
        if fnmatch.fnmatchcase(stem, spec.pattern):
            return spec
    return None


def ordered_figures(fig_dir: Path) -> list[tuple[Path, FigureSpec | None]]:
    """The PNGs of ``fig_dir`` in registry order (then unregistered ones by name)."""
    pngs = sorted(Path(fig_dir).glob("*.png")) if Path(fig_dir).exists() else []
    specs = figure_specs()
    rank = {spec.pattern: i for i, spec in enumerate(specs)}

    def key(p: Path):
        spec = spec_for(p.stem)
        return (rank[spec.pattern] if spec else len(specs), p.name)

    return [(p, spec_for(p.stem)) for p in sorted(pngs, key=key)]
