"""The task interface and what every task shares: outcomes, exclusions, rows, provenance, option specs.

A task is a registered plug-in (:class:`Task`, :func:`resti_lib.tasks.register_task`) that says only
what is specific to it:

``read_contract(row, video_map)``
    its contract ``C = (s, e, t, F, q, u, σ, D)`` read from a legacy row (:mod:`resti_lib.contract`);
``reconstruct(case)``
    resolve the referent and take the value from its registered measure operator
    (:meth:`Case.measure`), setting ``case.answer``; raise :class:`Exclude` when the row has no
    uniquely scoreable answer;
``diagnose(case)`` / ``diagnose_all(cases)``
    the hypotheses tested against the legacy value, concluding in an
    :class:`~resti_lib.adjudicate.Diagnosis` (``diagnose_all`` for hypotheses decided over a whole
    source, e.g. the statistic of "average speed");
``rewrite(case)``
    the question text that states the contract.

The runner (:mod:`resti_lib.tasks.run`) owns the rest, once: the :class:`Outcome` of each row,
legacy parsing, adjudication, answer-layer defects, exclusions, provenance and the option spec
handed to the option stage. :func:`finalize` prints each accepted answer (:func:`answer_text`),
hands the rows and their option specs to the option stage (:mod:`resti_lib.options.stage`, the
code ``resti reoption`` runs: candidates, balanced letters, evidence) and writes the ReSTI-schema
rows, the exclusion records and the provenance records. The options built here are the options the
release ships: the release stage collects them unchanged (every choice of the stage — groups,
letters, shared sets — lies within one task).
"""

from __future__ import annotations

import io
import json
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from .. import SCENE_OF_SOURCE, SOURCES
from .. import defaults as D
from .. import values as V
from ..adjudicate import Diagnosis, Rule, compare_scalar, rule_for
from ..contract import MISSING_DEFECTS, Contract
from ..errors import ContractError
from ..io.benchmark import jsonl_text, parse_key
from ..io.files import atomic_write_bytes
from ..measure import Measured, measure

#: Parameters every task shares, stated once in ``params/default.yaml`` (sources, legacy file, seed, outputs).
COMMON_KEYS = ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root", "scannet_fps", "omni6d_fps",
               "video_map", "seed", "output_dir")
KINDS = ("scalar", "angle", "box", "pose", "trajectory", "label")  # kinds of an AnswerSpec
VALUE_KINDS = ("scalar", "box", "pose", "trajectory", "label")  # kinds of a parsed value (an angle is a scalar)


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
    option_spec: dict | None = None

    def exclude(self, *reasons: str, **evidence) -> Outcome:
        self.verdict = "excluded"
        self.reasons = list(dict.fromkeys([*self.reasons, *reasons]))
        self.evidence.update(evidence)
        self.answer = None
        return self


class Exclude(Exception):
    """Raised in a task hook: the row is excluded with ``reasons`` (codes of
    :data:`resti_lib.defects.REASONS`), an optional defect code, and evidence."""

    def __init__(self, *reasons: str, defect: str | None = None, **evidence):
        super().__init__(", ".join(reasons))
        self.reasons, self.defect, self.evidence = list(reasons), defect, evidence

    def apply(self, o: Outcome) -> Outcome:
        if self.defect and self.defect not in o.defects:
            o.defects.append(self.defect)
        return o.exclude(*self.reasons, **self.evidence)


@dataclass(eq=False)
class Case:
    """One legacy row while its task works on it: the hooks read and fill it.

    ``legacy``: the Answer Detail parsed as the task's ``legacy_kind`` (None when unreadable,
    ``legacy_problem`` says why). ``answer``: the reconstructed answer; ``value``: the measured value
    (SI for scalars) the diagnosis compares. ``rule``: the comparison
    rule used (for the option spec). ``observables``: what the option stage may use besides the
    answer (subject, premise, ...). ``state``: the task's working data between its hooks.
    """

    task: Task
    row: dict
    outcome: Outcome
    contract: Contract
    legacy: V.Value | None
    legacy_problem: str | None
    ctx: Any
    params: dict
    answer: AnswerSpec | None = None
    value: Any = None
    diagnosis: Diagnosis | None = None
    rule: dict | None = None
    observables: dict = field(default_factory=dict)
    state: dict = field(default_factory=dict)

    @property
    def source(self) -> str:
        return self.outcome.source

    @property
    def detail(self):
        return self.row.get("Answer Detail")

    def measure(self, operator: str, entity: dict, times: list, **extra) -> Measured:
        """The value of ``operator`` on this row's sequence (the registered operator ``resti
        measure`` runs, with this run's params and opened sources). Raises ContractError."""
        c = self.contract
        contract = {"source": c.source, "sequence": c.sequence, "camera": c.camera, "entity": entity,
                    "times": [float(t) for t in times], "operator": operator, **extra}
        return measure(contract, self.params, sources=self.ctx)

    def provenance(self, *, files=None, frames=None, chain=None) -> None:
        """Record the source files read, the frames / timestamps used and the transform chain."""
        if files is not None:
            self.outcome.source_files = list(files)
        if frames is not None:
            self.outcome.frames = dict(frames)
        if chain is not None:
            self.outcome.transform_chain = chain


class Task:
    """A task plug-in (module docstring): the single descriptor of a task. Subclass, set the class
    attributes, implement the hooks, and register it with :func:`resti_lib.tasks.register_task`.

    Class attributes
    ----------------
    name : the legacy ``Task`` value. params_name : ``params/<params_name>.yaml`` holds its
    parameters and their defaults. notebook : its notebook ``notebooks/<notebook>.ipynb`` (``NN_`` +
    params_name), a stage of the main job. order : its place in tables and in the release (the
    benchmark's order). answer_kind : the :mod:`resti_lib.values` kind of its answers (``scalar``,
    ``box``, ``pose``, ``trajectory``, ``label``; an angle is a scalar). rule_key : the params key of
    its comparison rule (:meth:`rule`). quantity : what its questions measure, when
    :meth:`quantity_of` does not read it from the question. figures : the figures its notebook
    writes, ``{suffix: caption}`` for ``outputs/figures/<notebook>_<suffix>.png`` (a suffix may be a
    glob). legacy_kind : the :mod:`resti_lib.values` class(es) a legacy Answer Detail must parse
    to. operators : the measure operators its values come from. missing_defects :
    question-layer defect code per missing contract part.
    """

    name: ClassVar[str] = ""
    params_name: ClassVar[str] = ""
    notebook: ClassVar[str] = ""
    order: ClassVar[int] = 100
    answer_kind: ClassVar[str] = ""
    rule_key: ClassVar[str | None] = "rule"
    quantity: ClassVar[str] = "value"
    figures: ClassVar[dict[str, str]] = {}
    legacy_kind: ClassVar[type | tuple | None] = None
    operators: ClassVar[tuple[str, ...]] = ()
    missing_defects: ClassVar[dict] = {k: v for k, v in MISSING_DEFECTS.items() if k in ("unit", "subject")}
    setting_overrides: ClassVar[tuple[str, ...]] = ()
    follows: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def descriptor_problems(cls) -> list[str]:
        """What is wrong with the class attributes (empty when the task can be registered)."""
        out = []
        if not isinstance(cls.name, str) or not cls.name.strip():
            out.append("no task name")
        if not re.fullmatch(r"[a-z][a-z0-9_]*", str(cls.params_name)):
            out.append(f"params_name {cls.params_name!r} is not a lower-case file stem")
        elif not re.fullmatch(r"\d\d_" + re.escape(cls.params_name), str(cls.notebook)):
            out.append(f"notebook {cls.notebook!r} is not NN_{cls.params_name}")
        if cls.answer_kind not in VALUE_KINDS:
            out.append(f"answer_kind {cls.answer_kind!r} is not one of {VALUE_KINDS}")
        if not isinstance(cls.figures, dict) or not all(isinstance(k, str) and isinstance(v, str) and v.strip()
                                                        for k, v in cls.figures.items()):
            out.append("figures must map a file-name suffix to a caption")
        if not isinstance(cls.follows, tuple) or not all(isinstance(x, str) and x != cls.name for x in cls.follows):
            out.append("follows must be a tuple of other task names")
        for hook in ("read_contract", "reconstruct", "rewrite"):
            if getattr(cls, hook) is getattr(Task, hook):
                out.append(f"no {hook} hook")
        return out

    # -- parameters
    def settings(self, params: dict | None) -> dict:
        """The shared keys' defaults (``params/default.yaml``), then ``params/<params_name>.yaml``,
        overridden by ``params``: defaults written once, in the YAML files."""
        common = {k: v for k, v in D.load("default").items() if k in COMMON_KEYS}
        own = D.merged(self.params_name, params) if self.params_name else dict(params or {})
        return {**common, **own}

    def rule(self, settings: dict, source: str) -> Rule:
        """The comparison rule of the task on ``source`` (params ``rule_key``; no key: exact)."""
        return rule_for(settings, source, self.rule_key) if self.rule_key else Rule()

    def quantity_of(self, question: str) -> str:
        """What a (repaired) question of the task measures; the option stage and the attacks read it."""
        return self.quantity

    def interface(self, settings: dict):
        """What the answer interface knows of this task under ``settings`` (its params)."""
        from ..options.spec import TaskInterface

        return TaskInterface(self.answer_kind, {s: self.rule(settings, s) for s in SOURCES}, self.quantity_of)

    # -- hooks
    def read_contract(self, row: dict, video_map: dict | None = None) -> Contract:
        raise NotImplementedError

    def reconstruct(self, case: Case) -> None:
        raise NotImplementedError

    def contract_group(self, cases: list[Case]) -> None:
        """Contract repairs that need the task's other rows, after every row is reconstructed and before
        any is diagnosed (a Pose premise that is another row's answer). A case it excludes gets its
        outcome excluded (:meth:`Outcome.exclude`). Default: none."""

    def diagnose(self, case: Case) -> None:
        """Default: the scalar ``case.value`` (SI) compared with the legacy value under ``case.rule``."""
        rule = Rule(abs_tol=float(case.rule.get("abs_tol", 0.0)), rel_tol=float(case.rule.get("rel_tol", 0.0))) \
            if case.rule else Rule()
        cmp = compare_scalar(case.legacy, float(case.value), case.answer.unit, rule)
        case.diagnosis = Diagnosis.from_comparison(cmp)

    def diagnose_all(self, cases: list[Case]) -> None:
        for case in cases:
            self.diagnose(case)

    def rewrite(self, case: Case) -> str:
        raise NotImplementedError

    def question_defects(self, contract: Contract) -> list[str]:
        """Question-layer defect codes of the contract's missing parts."""
        return [self.missing_defects[m] for m in contract.missing if self.missing_defects.get(m)]


# ------------------------------------------------------------------------------------ helpers


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


# ------------------------------------------------------------------------------- option stage


def option_spec(o: Outcome, spec: AnswerSpec, *, rule: dict | None, observables: dict) -> dict:
    """What the task knows of one accepted row beyond its ReSTI fields, for the option stage:
    ``{kind, unit, decimals, rule, observables, labels}``. The stage reads the question's observables
    from the row itself (as ``resti reoption`` does); ``labels`` (the five choices of a categorical
    answer) come from here."""
    obs = {"time_start": o.time_start, "time_end": o.time_end,
           "window_s": None if o.time_start is None or o.time_end is None else float(o.time_end) - float(o.time_start),
           "source": o.source, "sequence": o.contract.get("sequence"), "camera": o.contract.get("camera"),
           **observables}
    out = {"kind": spec.kind, "unit": spec.unit, "decimals": spec.decimals, "rule": rule, "observables": obs}
    if spec.labels is not None:
        out["labels"] = list(spec.labels)
    return json.loads(_json(_round_floats(out, 9)))


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
    raise ContractError(f"unknown answer kind {spec.kind!r} (one of {', '.join(KINDS)})")


# --------------------------------------------------------------------------------- the output


@dataclass
class TaskResult:
    accepted: list
    excluded: list
    provenance: pd.DataFrame
    option_seconds: float = 0.0  # time spent in the option stage (reported by the scale benchmark)
    interface: dict = field(default_factory=dict)  # the answer interface the options were built with
    adversarial: list = field(default_factory=list)  # the adversarial filter's checks (Stage.adversarial_filter)


def finalize(outcomes: list[Outcome], legacy: pd.DataFrame, *, seed: int, iface, peers: list | None = None,
             peer_iface=None) -> TaskResult:
    """Options, letters, ReSTI rows, exclusion records and provenance for one task's outcomes.

    ``iface``: the run's answer interface (:class:`resti_lib.options.spec.Interface`: the option
    params and the task's comparison rule and question reader), recorded with the outputs so that
    the release and ``resti verify`` check the options against the params they were built with. A
    row whose options cannot be built under the constraints is excluded (``no_valid_options``),
    never shipped with weaker options. Outcomes come back in legacy row order. ``peers``: the
    accepted rows of the tasks this one follows (read under ``peer_iface``), whose candidate sets
    related rows follow (:mod:`resti_lib.options.follow`).
    """
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
        extras[rid] = o.option_spec or ({"labels": list(o.answer.labels or [])} if o.answer.kind == "label" else {})
        rows.append({
            "Video": legacy_row["Video"], "Source": o.source, "Task": o.task, "QType": "Single Choice",
            "Question": o.question, "Prompt": o.prompt if o.prompt is not None else (legacy_row.get("Prompt") or ""),
            "time_start": float(o.time_start), "time_end": float(o.time_end), "Candidates": {}, "Answer": None,
            "Answer Detail": detail, "ID": int(legacy_row["ID"]), "scene": SCENE_OF_SOURCE[o.source],
            "ReSTI ID": rid, "Legacy Row Key": o.key})
    t_opt = time.perf_counter()
    built, ev, failed = build_options(rows, iface=iface, seed=seed, extras=extras, on_failure="skip", peers=peers,
                                      peer_iface=peer_iface)
    t_opt = time.perf_counter() - t_opt
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
            "option_spec": _json(o.option_spec) if o.option_spec is not None and o.verdict != "excluded" else None,
        })
    return TaskResult(accepted, excluded, pd.DataFrame(prov), t_opt, iface.to_dict(), ev.attrs.get("adversarial", []))


def write_task_outputs(result: TaskResult, out_dir: str | Path) -> dict:
    """``accepted.jsonl``, ``excluded.jsonl``, ``provenance.parquet`` and ``interface.json`` (the
    answer interface its options were built with, and the adversarial filter's checks) of one task
    (atomic writes)."""
    out_dir = Path(out_dir)
    record = {**result.interface, "adversarial_filter": result.adversarial}
    atomic_write_bytes(out_dir / "interface.json", (_json(record) + "\n").encode("utf-8"))
    atomic_write_bytes(out_dir / "accepted.jsonl", jsonl_text(result.accepted).encode("utf-8"))
    atomic_write_bytes(out_dir / "excluded.jsonl", jsonl_text(result.excluded, sort_keys=True).encode("utf-8"))
    buf = io.BytesIO()
    result.provenance.to_parquet(buf, index=False, compression="zstd")
    atomic_write_bytes(out_dir / "provenance.parquet", buf.getvalue())
    return {"accepted": len(result.accepted), "excluded": len(result.excluded)}


def outcome_table(outcomes: list[Outcome]) -> pd.DataFrame:
    """A compact table of outcomes for notebooks (verdict, reasons, defects per row)."""
    return pd.DataFrame([{"row": o.row, "source": o.source, "video": o.video, "verdict": o.verdict,
                          "reasons": ",".join(o.reasons), "defects": ",".join(sorted(set(o.defects)))}
                         for o in outcomes])


__all__ = ["AnswerSpec", "Case", "Exclude", "Outcome", "Task", "TaskResult", "answer_text", "asdict", "finalize",
           "option_spec", "outcome_table", "resti_id", "slug", "write_task_outputs"]
