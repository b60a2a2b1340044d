"""What every task module returns, and the shared last steps: options, rows, exclusions, provenance.

A task module exposes ``audit(rows, ctx, params) -> list[Outcome]``: one :class:`Outcome` per legacy
row of its task (never fewer: a row it cannot handle is an exclusion with a reason). Then
:func:`finalize` builds the five candidates (``options.builders``), assigns balanced letters and
ranks, and writes the ReSTI-schema rows, the exclusion records and the provenance records.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .. import LETTERS, SCENE_OF_SOURCE
from ..io.benchmark import atomic_write_bytes, jsonl_text, parse_key
from ..options import builders as B
from ..rng import balanced_schedule, row_rng

KINDS = ("scalar", "angle", "box", "pose", "trajectory", "label")


@dataclass
class AnswerSpec:
    """The reconstructed answer in a form the option builders take.

    ``kind``: scalar (``value`` in ``unit``), angle (degrees), box (``value`` = dict centre/lwh/R),
    pose (4x4), trajectory (segments), label (``value`` text, ``labels`` the five choices).
    ``options``: keyword overrides for the builder (e.g. ``center_sigma``).
    """

    kind: str
    value: object
    unit: str | None = None
    decimals: int = 2
    labels: list | None = None
    options: dict = field(default_factory=dict)


@dataclass
class Outcome:
    """One legacy row after the three layers."""

    row: int
    key: str
    task: str
    source: str
    video: str
    legacy_id: object
    verdict: str
    reasons: list = field(default_factory=list)
    defects: list = field(default_factory=list)
    evidence: dict = field(default_factory=dict)
    contract: dict = field(default_factory=dict)
    question: str | None = None
    prompt: str | None = None
    time_start: float | None = None
    time_end: float | None = None
    answer: AnswerSpec | None = None
    legacy_detail: str | None = None
    source_files: list = field(default_factory=list)
    frames: dict = field(default_factory=dict)
    transform_chain: str = ""

    def exclude(self, *reasons: str, **evidence) -> "Outcome":
        self.verdict = "excluded"
        self.reasons = list(dict.fromkeys([*self.reasons, *reasons]))
        self.evidence.update(evidence)
        self.answer = None
        return self


@dataclass
class TaskResult:
    accepted: list
    excluded: list
    provenance: pd.DataFrame


def slug(task: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", task.lower()).strip("-")


def resti_id(task: str, key: str) -> str:
    return f"resti-{slug(task)}-{parse_key(key)['uid']}"


def _json(obj) -> str:
    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, (np.floating, np.integer)):
            return o.item()
        if isinstance(o, (set, tuple)):
            return list(o)
        return str(o)

    return json.dumps(obj, sort_keys=True, ensure_ascii=False, default=default)


def _round_floats(obj, nd: int = 6):
    if isinstance(obj, float):
        return round(obj, nd)
    if isinstance(obj, dict):
        return {k: _round_floats(v, nd) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_round_floats(v, nd) for v in obj]
    if isinstance(obj, np.ndarray):
        return _round_floats(obj.tolist(), nd)
    if isinstance(obj, (np.floating,)):
        return round(float(obj), nd)
    return obj


def build_options(spec: AnswerSpec, *, rng, target_rank: int | None, params: dict) -> B.Options:
    """Dispatch to the builder of the answer's kind, with params merged (spec overrides params)."""
    kw = {**params.get(spec.kind, {}), **spec.options}
    if spec.kind == "scalar":
        dec = B.scalar_decimals(float(spec.value), spec.decimals) if kw.pop("adapt_decimals", True) else spec.decimals
        return B.scalar_options(float(spec.value), spec.unit, rng=rng, decimals=dec, target_rank=target_rank,
                                **kw)
    if spec.kind == "angle":
        return B.angle_options(float(spec.value), rng=rng, decimals=spec.decimals, target_rank=target_rank, **kw)
    if spec.kind == "box":
        v = spec.value
        return B.box_options(v["center"], v["lwh"], v["R"], rng=rng, **kw)
    if spec.kind == "pose":
        return B.pose_options(np.asarray(spec.value), rng=rng, decimals=spec.decimals, **kw)
    if spec.kind == "trajectory":
        return B.trajectory_options(spec.value, rng=rng, **kw)
    if spec.kind == "label":
        return B.label_options(spec.value, list(spec.labels or []))
    raise ValueError(f"unknown answer kind {spec.kind!r}")


def finalize(outcomes: list[Outcome], legacy: pd.DataFrame, *, seed: int, option_params: dict | None = None
             ) -> TaskResult:
    """Options, letters, ReSTI rows, exclusion records and provenance for one task's outcomes.

    Ranks (scalar and angle answers) are balanced within each (task, source); letters within each
    task. Outcomes come back in legacy row order.
    """
    option_params = option_params or {}
    outcomes = sorted(outcomes, key=lambda o: o.row)
    by_row = {int(r["row"]): r for r in legacy.to_dict("records")}
    acc_keys = [o.key for o in outcomes if o.verdict != "excluded"]
    letters = {}
    for task in sorted({o.task for o in outcomes}):
        letters.update(balanced_schedule([o.key for o in outcomes if o.task == task and o.key in acc_keys],
                                         list(LETTERS), seed=seed, group=f"letters|{task}"))
    ranks = {}
    for grp in sorted({(o.task, o.source) for o in outcomes}):
        ks = [o.key for o in outcomes if (o.task, o.source) == grp and o.verdict != "excluded"
              and o.answer is not None and o.answer.kind in ("scalar", "angle")]
        ranks.update(balanced_schedule(ks, [1, 2, 3, 4, 5], seed=seed, group=f"ranks|{grp[0]}|{grp[1]}"))
    accepted, excluded, prov = [], [], []
    for o in outcomes:
        legacy_row = by_row[o.row]
        cands, letter, new_detail, opt_ev = None, None, None, {}
        if o.verdict != "excluded":
            rng = row_rng(seed, o.key, "options")
            try:
                opts = build_options(o.answer, rng=rng, target_rank=ranks.get(o.key), params=option_params)
                cands, letter = B.assign_letters(opts, letters[o.key], rng)
                new_detail = cands[letter]
                opt_ev = opts.evidence
            except B.OptionError as e:
                o.exclude("no_valid_options", option_error=str(e))
        rid = resti_id(o.task, o.key)
        if o.verdict == "excluded":
            rec = {"key": o.key, "legacy_id": legacy_row.get("ID"), "legacy_video": o.video, "source": o.source,
                   "task": o.task, "reason_codes": list(o.reasons) or ["unsupported_question"],
                   "verification_verdict": "excluded_" + (o.reasons[0] if o.reasons else "unsupported_question"),
                   "verification_evidence": _round_floats(o.evidence)}
            excluded.append(json.loads(_json(rec)))
        else:
            accepted.append({
                "Video": legacy_row["Video"], "Source": o.source, "Task": o.task, "QType": "Single Choice",
                "Question": o.question, "Prompt": o.prompt if o.prompt is not None else (legacy_row.get("Prompt") or ""),
                "time_start": float(o.time_start), "time_end": float(o.time_end), "Candidates": cands,
                "Answer": letter, "Answer Detail": new_detail, "ID": int(legacy_row["ID"]),
                "scene": SCENE_OF_SOURCE[o.source], "ReSTI ID": rid, "Legacy Row Key": o.key})
        prov.append({
            "row": o.row, "key": o.key, "resti_id": rid if o.verdict != "excluded" else None,
            "task": o.task, "source": o.source, "video": o.video, "verdict": o.verdict,
            "reasons": _json(o.reasons), "defects": _json(sorted(set(o.defects))),
            "contract": _json(_round_floats(o.contract)), "source_files": _json(o.source_files),
            "frames": _json(_round_floats(o.frames)), "transform_chain": o.transform_chain,
            "evidence": _json(_round_floats({**o.evidence, **({"options": opt_ev} if opt_ev else {})})),
            "legacy_detail": o.legacy_detail, "new_detail": new_detail,
        })
    return TaskResult(accepted, excluded, pd.DataFrame(prov))


def write_task_outputs(result: TaskResult, out_dir: str | Path) -> dict:
    """``accepted.jsonl``, ``excluded.jsonl`` and ``provenance.parquet`` of one task (atomic writes)."""
    out_dir = Path(out_dir)
    atomic_write_bytes(out_dir / "accepted.jsonl", jsonl_text(result.accepted).encode("utf-8"))
    atomic_write_bytes(out_dir / "excluded.jsonl", jsonl_text(result.excluded, sort_keys=True).encode("utf-8"))
    import io

    buf = io.BytesIO()
    result.provenance.to_parquet(buf, index=False, compression="zstd")
    atomic_write_bytes(out_dir / "provenance.parquet", buf.getvalue())
    return {"accepted": len(result.accepted), "excluded": len(result.excluded)}


def outcome_table(outcomes: list[Outcome]) -> pd.DataFrame:
    """A compact table of outcomes for notebooks (verdict, reasons, defects per row)."""
    return pd.DataFrame([{"row": o.row, "source": o.source, "video": o.video, "verdict": o.verdict,
                          "reasons": ",".join(o.reasons), "defects": ",".join(sorted(set(o.defects)))}
                         for o in outcomes])


__all__ = ["AnswerSpec", "Outcome", "TaskResult", "finalize", "write_task_outputs", "resti_id", "slug",
           "outcome_table", "asdict"]
