"""The shared path of every task: legacy rows -> outcomes -> options -> files under outputs/.

``run_task(task, params)`` loads the legacy benchmark (non-strict: a malformed row becomes an
exclusion with reason ``malformed_row``, never a dropped row), opens the sources, excludes exact
duplicate rows and rows asking a time past the end of the video (:func:`prescreen`) and calls
:func:`audit_rows`, which for each row of the task

1. makes its :class:`~resti_lib.tasks.base.Outcome` and reads its contract (``Task.read_contract``;
   the question-layer defects of its missing parts follow);
2. parses the legacy Answer Detail once (:func:`resti_lib.adjudicate.read_legacy`);
3. reconstructs the value (``Task.reconstruct``; an :class:`~resti_lib.tasks.base.Exclude` ends the
   row excluded with its reasons and evidence, and so does damaged or gapped source data,
   :class:`~resti_lib.errors.SourceError`: ``source_damaged`` / ``source_gap`` with file, row and field),
   then repairs what needs the task's other rows (``Task.contract_group``);
4. diagnoses the legacy value (``Task.diagnose_all``) and adjudicates the verdict;
5. rewrites the question (``Task.rewrite``), completes the contract (σ and D of the repaired
   row, what the legacy row stated kept under ``legacy``) and the option spec;
6. adds the answer-layer defects of the legacy row (the registry of :mod:`resti_lib.adjudicate`).

Then :func:`~resti_lib.tasks.base.finalize` builds the options and the rows, and the files
``<output_dir>/tasks/<slug>/{accepted.jsonl, excluded.jsonl, provenance.parquet}`` are written.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import paths
from ..adjudicate import answer_layer_defects, group_shortcuts, read_legacy
from ..errors import ContractError, InputError, SourceError, SourceGapError
from ..io.benchmark import canonical_row_text, load_legacy
from ..options.spec import Interface, load_option_params
from ..sources.context import SourceContext
from . import interface, names, task_for
from .base import Case, Exclude, Outcome, Task, TaskResult, finalize, option_spec, slug, write_task_outputs


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

    def attack_tables(self, *, alpha: float = 0.05) -> tuple[pd.DataFrame, pd.DataFrame]:
        """The option-only attack table of the task's accepted rows (the options it ships) and of
        its legacy rows (a hit is the keyed letter), Holm within each: the one way a task notebook
        tables its attacks."""
        from ..options.attacks import attack_table

        iface = interface()
        return (attack_table(self.result.accepted, iface=iface, alpha=alpha),
                attack_table(self.legacy.to_dict("records"), iface=iface, alpha=alpha))


def legacy_rows_of(task: str, legacy_path) -> tuple[pd.DataFrame, list]:
    """The legacy rows of one task (non-strict: problems come back as records, rows are kept)."""
    return load_legacy(paths.resolve(legacy_path), strict=False, tasks=[task], known_tasks=names())


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


def _outcome(task: Task, r: dict) -> Outcome:
    return Outcome(row=int(r["row"]), key=str(r["Legacy Row Key"]), task=task.name, source=str(r["Source"]),
                   video=str(r["Video"]), legacy_id=r.get("ID"), verdict="re-contracted",
                   legacy_detail=None if r.get("Answer Detail") is None else str(r.get("Answer Detail")))


def _complete(case: Case) -> None:
    """The accepted row's contract states σ and D of the repair; the legacy ones move to ``legacy``."""
    c, a, o = case.contract, case.answer, case.outcome
    c.legacy = {"missing": list(c.missing), "format": c.format, "distractors": c.distractors,
                **c.legacy}
    c.missing = []
    c.format = {"kind": a.kind, "unit": a.unit, "decimals": a.decimals,
                **({"labels": list(a.labels)} if a.labels is not None else {})}
    spec = option_spec(o, a, rule=case.rule, observables=case.observables)
    c.distractors = {"policy": "four draws exchangeable with the answer from the answers of its task and source "
                               "given the question's observables (params/options.yaml), separated and physically "
                               "possible, letters balanced" if a.kind != "label" else
                               "the fixed labels of the source", "rule": case.rule}
    o.option_spec = spec


def audit_rows(task: Task, rows: pd.DataFrame, ctx: SourceContext, params: dict) -> list[Outcome]:
    """The shared path (module docstring, steps 1-5) for the legacy rows of one task."""
    params = task.settings(params)
    cases: list[Case] = []
    outcomes: list[Outcome] = []
    for r in rows.to_dict("records"):
        o = _outcome(task, r)
        outcomes.append(o)
        c = task.read_contract(r, ctx.video_map)
        o.contract = c.to_dict()
        o.defects += task.question_defects(c)
        legacy, problem = read_legacy(r, task.legacy_kind)
        if problem:
            o.evidence["legacy_unreadable"] = problem
        case = Case(task, r, o, c, legacy, problem, ctx, params)
        try:
            task.reconstruct(case)
        except Exclude as e:
            o.contract = c.to_dict()
            e.apply(o)
            continue
        except SourceError as e:  # damaged or gapped source data: named, never measured
            o.contract = c.to_dict()
            o.exclude("source_gap" if isinstance(e, SourceGapError) else "source_damaged", source_file=e.file,
                      source_row=e.row, source_field=e.field, problem=e.message)
            continue
        cases.append(case)
    task.contract_group(cases)
    task.diagnose_all([c for c in cases if c.outcome.verdict != "excluded"])
    for case in cases:
        o, d = case.outcome, case.diagnosis
        if o.verdict == "excluded":  # a group-level contract repair or diagnosis may exclude
            o.contract = case.contract.to_dict()
            continue
        if case.answer is None or d is None:
            raise ContractError(f"{task.name}: row {o.row} has no answer or no diagnosis and no exclusion")
        o.verdict = d.final_verdict
        o.defects += [x for x in d.defects if x not in o.defects]
        o.evidence.update(d.evidence)
        o.question = task.rewrite(case)
        if o.prompt is None:
            o.prompt = case.row.get("Prompt") or ""
        o.answer = case.answer
        _complete(case)
        o.contract = case.contract.to_dict()
    return outcomes


def audit_row(task: str | Task, row: dict, ctx, params: dict) -> Outcome:
    """One legacy row (a dict with ``row`` and ``Legacy Row Key``) through the shared path, without
    the answer-layer step and the options: for checks of a task on hand-made rows."""
    t = task if isinstance(task, Task) else task_for(task)
    return audit_rows(t, pd.DataFrame([row]), ctx, params)[0]


def _answer_layer(outcomes: list[Outcome], mine: pd.DataFrame) -> None:
    """Step 6: answer-layer defects of each legacy row (row checks and group checks)."""
    records = {int(r["row"]): r for r in mine.to_dict("records")}
    shortcuts = group_shortcuts(list(records.values()))
    position = {row: i for i, row in enumerate(records)}  # group checks key rows by list position
    for o in outcomes:
        d, ev = answer_layer_defects(records[o.row])
        o.defects = list(dict.fromkeys([*o.defects, *d, *shortcuts.get(position[o.row], [])]))
        if ev:
            o.evidence.setdefault("answer_layer", ev)


def run_rows(task: str | Task, mine: pd.DataFrame, params: dict, *, problems: list | None = None,
             ctx: SourceContext | None = None) -> TaskRun:
    """Audit legacy rows of one task (``mine``: qa.parquet columns plus ``row`` and ``Legacy Row
    Key``) and write its files. ``problems``: rows that could not be read (``malformed_row``)."""
    t = task if isinstance(task, Task) else task_for(task)
    params = t.settings(params)
    bad_rows = {p.row: p for p in (problems or [])}
    ctx = ctx or SourceContext.from_params(params)
    rows_ok, screened, extra = prescreen(mine[~mine["row"].isin(bad_rows)], ctx, t.name)
    outcomes = audit_rows(t, rows_ok, ctx, params) if len(rows_ok) else []
    outcomes += screened
    for o in outcomes:
        o.defects = list(dict.fromkeys([*o.defects, *extra.get(o.row, [])]))
    for r in mine[mine["row"].isin(bad_rows)].to_dict("records"):
        p = bad_rows[r["row"]]
        o = _outcome(t, r)
        o.legacy_detail = str(r.get("Answer Detail"))
        outcomes.append(o.exclude("malformed_row", field=p.field, problem=p.message))
    _answer_layer(outcomes, mine)
    iface = Interface(load_option_params(), {t.name: t.interface(params)})
    out_dir = paths.resolve(params.get("output_dir") or "outputs") / "tasks" / slug(t.name)
    peers, peer_iface = followed_rows(t, out_dir.parent, iface.options)
    result = finalize(outcomes, mine, seed=int(params["seed"]), iface=iface, peers=peers, peer_iface=peer_iface)
    write_task_outputs(result, out_dir)
    return TaskRun(t.name, sorted(outcomes, key=lambda o: o.row), result, out_dir, mine)


def followed_rows(t: Task, tasks_dir: Path, options: dict) -> tuple[list[dict], Interface | None]:
    """The accepted rows of the tasks ``t`` follows (``Task.follows``), as their stages of this run
    wrote them to ``tasks_dir/<slug>/accepted.jsonl`` (the main job runs those stages first), and the
    answer interface that reads them (under the run's option params ``options``). A task run alone,
    without them, draws its own candidate sets."""
    from ..io.files import read_jsonl

    rows, tasks = [], {}
    for name in t.follows:
        f = Path(tasks_dir) / slug(name) / "accepted.jsonl"
        if f.is_file():
            d = task_for(name)
            rows += read_jsonl(f)
            tasks[name] = d.interface(d.settings({}))
    return rows, (Interface(options, tasks) if tasks else None)


def run_task(task: str, params: dict) -> TaskRun:
    """Audit one task end to end and write its files. ``params``: the notebook's parameters (checked
    against the task's defaults first: a value of the wrong type or out of range is refused by name,
    whether it came from ``resti run`` or straight from papermill)."""
    from ..defaults import check_params

    t = task_for(task)
    check_params(params, t.settings({}), file="notebook parameters", what=f"params of {t.notebook}")
    legacy, problems = legacy_rows_of(task, params["legacy_benchmark"])
    mine = legacy[legacy["Task"] == task]
    return run_rows(task, mine, params, problems=problems)
