"""What every task module returns, and the shared last steps: options, rows, exclusions, provenance.

A task module exposes ``audit(rows, ctx, params) -> list[Outcome]``: one :class:`Outcome` per legacy
row of its task (never fewer: a row it cannot handle is an exclusion with a reason). Then
:func:`finalize` prints each accepted answer (:func:`answer_text`), hands the rows to the option
stage (:mod:`resti_lib.options.stage`, the code ``resti reoption`` runs: candidates, balanced
letters, evidence) and writes the ReSTI-schema rows, the exclusion records and the provenance
records. The options built here are the options the release ships: the release stage collects
them unchanged (every choice of the stage — groups, letters, shared sets — lies within one task).
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .. import SCENE_OF_SOURCE
from .. import values as V
from ..io.benchmark import atomic_write_bytes, jsonl_text, parse_key

KINDS = ("scalar", "angle", "box", "pose", "trajectory", "label")


@dataclass
class AnswerSpec:
    """The reconstructed answer, printed by :func:`answer_text`.

    ``kind``: scalar (``value`` in ``unit``), angle (degrees), box (``value`` = dict centre/lwh/R),
    pose (4x4), trajectory (segments), label (``value`` text, ``labels`` the five choices).
    ``options``: printing options (``compact`` pose JSON, ``adapt_decimals`` for small scalars).
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


def answer_text(spec: AnswerSpec) -> str:
    """The answer string of an accepted row (``Answer Detail``), printed by :mod:`resti_lib.values`.

    Scalars below 20 printed units take more decimals (0.063 m prints as ``0.063m``), unless the
    task says ``adapt_decimals: False``."""
    kw = spec.options or {}
    if spec.kind == "scalar":
        dec = V.adaptive_decimals(float(spec.value), spec.decimals) if kw.get("adapt_decimals", True) else spec.decimals
        return V.format_scalar(float(spec.value), spec.unit, dec)
    if spec.kind == "angle":
        return V.format_angle(float(spec.value), spec.decimals)
    if spec.kind == "box":
        v = spec.value
        return V.format_box(v["center"], v["lwh"], v["R"])
    if spec.kind == "pose":
        return V.format_pose(np.asarray(spec.value), spec.decimals, compact=bool(kw.get("compact", False)))
    if spec.kind == "trajectory":
        return V.format_trajectory(spec.value)
    if spec.kind == "label":
        return str(spec.value)
    raise ValueError(f"unknown answer kind {spec.kind!r}")


def finalize(outcomes: list[Outcome], legacy: pd.DataFrame, *, seed: int, option_params: dict | None = None
             ) -> TaskResult:
    """Options, letters, ReSTI rows, exclusion records and provenance for one task's outcomes.

    ``option_params``: overrides of ``params/options.yaml``. A row whose options cannot be built
    under the constraints is excluded (``no_valid_options``), never shipped with weaker options.
    Outcomes come back in legacy row order.
    """
    from ..options.spec import load_option_params
    from ..options.stage import build_options

    outcomes = sorted(outcomes, key=lambda o: o.row)
    by_row = {int(r["row"]): r for r in legacy.to_dict("records")}
    rows, extras, index = [], {}, {}
    for o in outcomes:
        if o.verdict == "excluded":
            continue
        legacy_row = by_row[o.row]
        rid = resti_id(o.task, o.key)
        try:
            detail = answer_text(o.answer)
        except (ValueError, KeyError, TypeError) as e:
            o.exclude("no_valid_options", option_error=f"answer cannot be printed: {e}")
            continue
        index[rid] = o
        if o.answer.kind == "label":
            extras[rid] = {"labels": list(o.answer.labels or [])}
        rows.append({
            "Video": legacy_row["Video"], "Source": o.source, "Task": o.task, "QType": "Single Choice",
            "Question": o.question, "Prompt": o.prompt if o.prompt is not None else (legacy_row.get("Prompt") or ""),
            "time_start": float(o.time_start), "time_end": float(o.time_end), "Candidates": {}, "Answer": None,
            "Answer Detail": detail, "ID": int(legacy_row["ID"]), "scene": SCENE_OF_SOURCE[o.source],
            "ReSTI ID": rid, "Legacy Row Key": o.key})
    built, ev, failed = build_options(rows, seed=seed, params=load_option_params(option_params), extras=extras,
                                      on_failure="skip")
    for rid, problem in failed.items():
        index[rid].exclude("no_valid_options", option_error=problem)
    opt_ev = {r["rid"]: {k: v for k, v in r.items() if k not in ("rid", "task", "source") and v == v}
              for r in ev.to_dict("records")} if len(ev) else {}
    shipped = {r["ReSTI ID"]: r for r in built if r["ReSTI ID"] not in failed}
    accepted, excluded, prov = [], [], []
    for o in outcomes:
        legacy_row = by_row[o.row]
        rid = resti_id(o.task, o.key)
        row = shipped.get(rid) if o.verdict != "excluded" else None
        new_detail = row["Answer Detail"] if row else None
        if o.verdict == "excluded":
            rec = {"key": o.key, "legacy_id": legacy_row.get("ID"), "legacy_video": o.video, "source": o.source,
                   "task": o.task, "reason_codes": list(o.reasons) or ["unsupported_question"],
                   "verification_verdict": "excluded_" + (o.reasons[0] if o.reasons else "unsupported_question"),
                   "verification_evidence": _round_floats(o.evidence)}
            excluded.append(json.loads(_json(rec)))
        else:
            accepted.append(row)
        evidence = {**o.evidence, **({"options": opt_ev[rid]} if row is not None and rid in opt_ev else {})}
        prov.append({
            "row": o.row, "key": o.key, "resti_id": rid if o.verdict != "excluded" else None,
            "task": o.task, "source": o.source, "video": o.video, "verdict": o.verdict,
            "reasons": _json(o.reasons), "defects": _json(sorted(set(o.defects))),
            "contract": _json(_round_floats(o.contract)), "source_files": _json(o.source_files),
            "frames": _json(_round_floats(o.frames)), "transform_chain": o.transform_chain,
            "evidence": _json(_round_floats(evidence)),
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


__all__ = ["AnswerSpec", "Outcome", "TaskResult", "answer_text", "finalize", "write_task_outputs", "resti_id",
           "slug", "outcome_table", "asdict"]
