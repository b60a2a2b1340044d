"""One call per task notebook: legacy rows of the task -> outcomes -> options -> files under outputs/.

``run_task(task, params)`` loads the legacy benchmark (non-strict: a malformed row becomes an
exclusion with reason ``malformed_row``, never a dropped row), opens the sources, calls the task
module's ``audit``, adds the answer-layer defects of each legacy row, builds the options and writes
``<output_dir>/tasks/<slug>/{accepted.jsonl, excluded.jsonl, provenance.parquet}``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from .. import paths
from ..adjudicate import answer_layer_defects, group_shortcuts
from ..io.benchmark import load_legacy
from ..sources.context import SourceContext
from . import module_for
from .base import Outcome, TaskResult, finalize, slug, write_task_outputs

COMMON_KEYS = ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root", "scannet_fps", "omni6d_fps",
               "video_map", "seed", "output_dir")


@dataclass
class TaskRun:
    task: str
    outcomes: list
    result: TaskResult
    out_dir: Path
    legacy: pd.DataFrame

    @property
    def summary(self) -> pd.DataFrame:
        """Verdict counts per source (the task's row of the coverage table)."""
        df = pd.DataFrame([{"source": o.source, "verdict": o.verdict} for o in self.outcomes])
        if df.empty:
            return df
        t = df.pivot_table(index="source", columns="verdict", aggfunc="size", fill_value=0)
        t["total"] = t.sum(axis=1)
        return t.reset_index()

    @property
    def reasons(self) -> pd.Series:
        return pd.Series([r for o in self.outcomes for r in o.reasons], dtype=object).value_counts()

    @property
    def defects(self) -> pd.Series:
        return pd.Series([d for o in self.outcomes for d in dict.fromkeys(o.defects)], dtype=object).value_counts()


def legacy_rows_of(task: str, legacy_path) -> tuple[pd.DataFrame, list]:
    """The legacy rows of one task (non-strict: problems come back as records, rows are kept)."""
    return load_legacy(paths.resolve(legacy_path), strict=False, tasks=[task])


def run_task(task: str, params: dict) -> TaskRun:
    """Audit one task end to end and write its files. ``params``: the notebook's parameters."""
    legacy, problems = legacy_rows_of(task, params["legacy_benchmark"])
    bad_rows = {p.row: p for p in problems}
    mine = legacy[legacy["Task"] == task]
    ctx = SourceContext.from_params(params)
    rows_ok = mine[~mine["row"].isin(bad_rows)]
    module = module_for(task)
    outcomes: list[Outcome] = module.audit(rows_ok, ctx, params) if len(rows_ok) else []
    seen = {o.row for o in outcomes}
    missing = sorted(set(rows_ok["row"]) - seen)
    if missing:
        raise RuntimeError(f"{task}: audit returned no outcome for legacy rows {missing[:10]}")
    for r in mine[mine["row"].isin(bad_rows)].to_dict("records"):
        p = bad_rows[r["row"]]
        outcomes.append(Outcome(row=int(r["row"]), key=r["Legacy Row Key"], task=task, source=str(r["Source"]),
                                video=str(r["Video"]), legacy_id=r.get("ID"), verdict="excluded",
                                reasons=["malformed_row"],
                                evidence={"field": p.field, "problem": p.message},
                                legacy_detail=str(r.get("Answer Detail"))))
    records = {int(r["row"]): r for r in mine.to_dict("records")}
    shortcuts = group_shortcuts(list(records.values()))
    position = {row: i for i, row in enumerate(records)}  # group_shortcuts keys rows by list position
    for o in outcomes:
        d, ev = answer_layer_defects(records[o.row])
        o.defects = list(dict.fromkeys([*o.defects, *d, *shortcuts.get(position[o.row], [])]))
        if ev:
            o.evidence.setdefault("answer_layer", ev)
    result = finalize(outcomes, mine, seed=int(params.get("seed", 0)))
    out_dir = paths.resolve(params.get("output_dir") or "outputs") / "tasks" / slug(task)
    write_task_outputs(result, out_dir)
    return TaskRun(task, sorted(outcomes, key=lambda o: o.row), result, out_dir, mine)
