"""One call per task notebook: legacy rows of the task -> outcomes -> options -> files under outputs/.

``run_task(task, params)`` loads the legacy benchmark (non-strict: a malformed row becomes an
exclusion with reason ``malformed_row``, never a dropped row), opens the sources, excludes exact
duplicate rows and rows asking a time past the end of the video (:func:`prescreen`), calls the task
module's ``audit``, adds the answer-layer defects of each legacy row, builds the options and writes
``<output_dir>/tasks/<slug>/{accepted.jsonl, excluded.jsonl, provenance.parquet}``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import paths
from ..adjudicate import answer_layer_defects, group_shortcuts
from ..errors import ContractError, InputError
from ..io.benchmark import canonical_row_text, load_legacy
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


def _excluded(r: dict, task: str, reason: str, defect: str, **evidence) -> Outcome:
    return Outcome(row=int(r["row"]), key=r["Legacy Row Key"], task=task, source=str(r["Source"]),
                   video=str(r["Video"]), legacy_id=r.get("ID"), verdict="excluded", reasons=[reason],
                   defects=[defect], evidence=evidence, legacy_detail=str(r.get("Answer Detail")))


def video_sample_times(ctx: SourceContext, video: str) -> np.ndarray | None:
    """Times (s) of the source samples of a video, where the source gives them: ScanNet ``.sens``
    frames (``frame / fps``), Waymo ``vehicle_pose`` frames (``(micros - first) / 1e6``), ROPE
    meta frames (``frame / fps``). ``None`` when the source cannot say (the task reports why)."""
    try:
        vs = ctx.locate(video)
        if vs.source == "ScanNet":
            return np.asarray(ctx.scannet(vs.sequence).camera_track().times, float)
        if vs.source == "Waymo":
            return np.asarray(ctx.waymo(vs.sequence).ego_track().times, float)
        rp = ctx.rope(vs.sequence)
        return np.asarray(rp.frames, float) / rp.fps
    except (InputError, ContractError):
        return None


def video_end(times: np.ndarray) -> tuple[float, float]:
    """End of a video sampled at ``times`` (the last sample plus one median sampling interval: a
    video of N frames lasts N intervals) and the tolerance on it (half an interval, so that
    rounded times and either frame-time convention never read as past the end)."""
    step = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    return float(times[-1]) + step, max(0.5 * step, 1e-6)


def prescreen(rows: pd.DataFrame, ctx: SourceContext, task: str) -> tuple[pd.DataFrame, list[Outcome], dict]:
    """Exclusions every task shares, decided before the task measures anything.

    - **exact duplicates**: rows whose every legacy field equals an earlier row's; the first is
      kept and audited (defect ``duplicate_row``), the copies are excluded (reason ``duplicate_row``,
      evidence: the kept row);
    - **times past the end of the video**: ``time_start`` or ``time_end`` after the end of the
      video (:func:`video_end` of the source's samples, beyond its tolerance) — excluded, reason and
      defect ``time_past_video_end``.

    Returns the rows left for the task, the excluded outcomes and extra defects per kept row.
    """
    keep, out, extra = [], [], {}
    first: dict[str, dict] = {}
    ends: dict[str, tuple[float, float] | None] = {}
    for r in rows.to_dict("records"):
        text = canonical_row_text(r)
        if text in first:
            k = first[text]
            extra.setdefault(int(k["row"]), ["duplicate_row"])
            out.append(_excluded(r, task, "duplicate_row", "duplicate_row", duplicate_of=k["Legacy Row Key"],
                                 duplicate_of_row=int(k["row"])))
            continue
        first[text] = r
        video = str(r["Video"])
        if video not in ends:
            times = video_sample_times(ctx, video)
            ends[video] = video_end(times) if times is not None and len(times) else None
        if ends[video] is not None:
            end, tol = ends[video]
            late = {f: float(r[f]) for f in ("time_start", "time_end") if float(r[f]) > end + tol}
            if late:
                out.append(_excluded(r, task, "time_past_video_end", "time_past_video_end", video_end_s=end,
                                     tolerance_s=tol, late_times=late))
                continue
        keep.append(int(r["row"]))
    return rows[rows["row"].isin(keep)], out, extra


def run_task(task: str, params: dict) -> TaskRun:
    """Audit one task end to end and write its files. ``params``: the notebook's parameters."""
    legacy, problems = legacy_rows_of(task, params["legacy_benchmark"])
    bad_rows = {p.row: p for p in problems}
    mine = legacy[legacy["Task"] == task]
    ctx = SourceContext.from_params(params)
    rows_ok, screened, extra = prescreen(mine[~mine["row"].isin(bad_rows)], ctx, task)
    module = module_for(task)
    outcomes: list[Outcome] = module.audit(rows_ok, ctx, params) if len(rows_ok) else []
    seen = {o.row for o in outcomes}
    missing = sorted(set(rows_ok["row"]) - seen)
    if missing:
        raise RuntimeError(f"{task}: audit returned no outcome for legacy rows {missing[:10]}")
    outcomes += screened
    for o in outcomes:
        o.defects = list(dict.fromkeys([*o.defects, *extra.get(o.row, [])]))
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
    result = finalize(outcomes, mine, seed=int(params.get("seed", 0)), option_params=params.get("options") or {})
    out_dir = paths.resolve(params.get("output_dir") or "outputs") / "tasks" / slug(task)
    write_task_outputs(result, out_dir)
    return TaskRun(task, sorted(outcomes, key=lambda o: o.row), result, out_dir, mine)
