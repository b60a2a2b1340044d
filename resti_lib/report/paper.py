"""The ReSTI report against what we measure: every quantitative claim we can check, with its status.

The claims live in ``paper_claims.yaml`` beside this module (the report's words and figures, in panel
order); each names a measurement registered here (:data:`MEASURES`) and what it needs:

- ``v5``: the public ReSTI v5 release (its rows, exclusions, ``resti verify`` result and the attack
  table of :func:`resti_lib.release.audit.attack_release`), measured by notebook 00
  (:func:`v5_claims`);
- ``legacy``: the real STI-Bench legacy benchmark, measured from the tables of our run by notebook 99
  (:func:`legacy_claims`); on the synthetic mini-world they are *not checkable here* and the
  synthetic figure is shown beside, for what it is;
- ``none``: data that is not here (the claim says why).

A claim is *reproduced* when the measured figure equals the report's (counts exactly; a share at the
decimals the report prints; ``at_least``/``at_most`` bounds), *not reproduced* otherwise. Blind-attack
leaks of v5 that the report does not mention are added to the v5 table (status *leak not in the
report*). The index shows both tables as one panel (:func:`panel`).
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import pandas as pd
import yaml

from .. import LETTERS
from .. import values as V
from ..errors import InputError, RestiError
from .exclusions import verdict_class

CLAIMS_FILE = Path(__file__).with_name("paper_claims.yaml")
COLUMNS = ["id", "section", "claim", "ReSTI report", "measured", "status", "how"]
REPRODUCED, NOT_REPRODUCED, NOT_CHECKABLE, LEAK = ("reproduced", "not reproduced", "not checkable here",
                                                   "leak not in the report")
STATUSES = (REPRODUCED, NOT_REPRODUCED, NOT_CHECKABLE, LEAK)
FULL_COVERAGE = 0.999


@dataclass(frozen=True)
class Claim:
    id: str
    section: str
    claim: str
    paper: str
    measure: str
    needs: str
    value: object = None
    compare: str = "equal"
    decimals: int | None = None
    args: dict = field(default_factory=dict)


@lru_cache(maxsize=1)
def load_claims() -> tuple[Claim, ...]:
    """The claims of ``paper_claims.yaml``, in panel order."""
    raw = yaml.safe_load(CLAIMS_FILE.read_text(encoding="utf-8"))
    return tuple(Claim(**{k: (v if k != "args" else dict(v or {})) for k, v in c.items()}) for c in raw)


@dataclass(frozen=True)
class Measured:
    """A measured figure: ``value`` (a number, or ``(hits, rows)``), its text, and how it was measured."""

    value: object
    text: str
    how: str


class NotCheckable(RestiError):
    """A measurement that cannot be made here (the message says why): the claim's status, never an
    error of the run."""


@dataclass
class V5Evidence:
    accepted: pd.DataFrame
    excluded: list[dict]
    attacks: pd.DataFrame | None = None
    validation: dict | None = None


@dataclass
class RunEvidence:
    tables: dict[str, pd.DataFrame]
    real: bool


MEASURES: dict[str, Callable] = {}


def measure(name: str):
    def deco(fn):
        MEASURES[name] = fn
        return fn
    return deco


def _hits(h: float, n: int) -> str:
    """``37/185 = 20.0%``; expected hits of tied picks with one decimal (``95.1/314 = 30.3%``)."""
    ht = f"{h:.0f}" if abs(h - round(h)) < 1e-9 else f"{h:.1f}"
    return f"{ht}/{n} = {h / n:.1%}" if n else f"{ht}/0"


# ------------------------------------------------------------------------------- v5 measurements

@measure("v5_count")
def _v5_count(ev: V5Evidence, *, part: str, task: str | None = None, source: str | None = None) -> Measured:
    acc = ev.accepted
    sel_a = pd.Series(True, index=acc.index)
    if task is not None:
        sel_a &= acc["Task"] == task
    if source is not None:
        sel_a &= acc["Source"] == source
    n_exc = sum(1 for r in ev.excluded if (task is None or r.get("task") == task)
                and (source is None or r.get("source") == source))
    n = {"accepted": int(sel_a.sum()), "excluded": n_exc, "total": int(sel_a.sum()) + n_exc}[part]
    where = " ".join(x for x in (task, source) if x) or "all"
    return Measured(n, f"{n:,}", f"{part} rows of v5 ({where})")


def _attack_rows(ev: V5Evidence, task: str) -> pd.DataFrame:
    if ev.attacks is None:
        raise NotCheckable("no attack table of v5 (notebook 00)")
    t = ev.attacks
    return t[(t["task"] == task) & (t["source"] == "ALL")]


@measure("v5_attack")
def _v5_attack(ev: V5Evidence, *, task: str, attacks: list[str]) -> Measured:
    t = _attack_rows(ev, task)
    t = t[t["attack"].isin(attacks)].sort_values(["hits", "attack"], ascending=[False, True], kind="stable")
    if t.empty:
        raise NotCheckable(f"none of the attacks {attacks} ran on {task}")
    b = t.iloc[0]
    what = f"attack {b['attack']}" if len(attacks) == 1 else f"best of {', '.join(attacks)}: {b['attack']}"
    return Measured((float(b["hits"]), int(b["picked"])), _hits(float(b["hits"]), int(b["picked"])),
                    f"{what} (resti attack on v5)")


@measure("v5_strongest")
def _v5_strongest(ev: V5Evidence, *, task: str, family: str, named: dict | None = None) -> Measured:
    t = _attack_rows(ev, task)
    full = t[t["coverage"].astype(float) >= FULL_COVERAGE]
    fam = full[full["family"] == family].sort_values(["accuracy", "hits"], ascending=False, kind="stable")
    if fam.empty:
        raise NotCheckable(f"no full-coverage {family} attack ran on {task}")
    b = fam.iloc[0]
    how = f"our strongest full-coverage {family} attack: {b['attack']}" + \
          (" (Holm-significant)" if str(b["significant"]) == "True" else "")
    if named:
        nm = fam[fam["attack"].isin(named["attacks"])]
        if len(nm):
            n = nm.iloc[0]
            how += f"; {named['what']}: best {n['attack']} {_hits(float(n['hits']), int(n['picked']))}"
    best = full.sort_values(["accuracy", "hits"], ascending=False, kind="stable").iloc[0]
    if best["attack"] != b["attack"]:
        how += (f"; the whole suite: {best['attack']} ({best['family']}) "
                f"{_hits(float(best['hits']), int(best['picked']))}")
    return Measured((float(b["hits"]), int(b["picked"])), _hits(float(b["hits"]), int(b["picked"])), how)


def _angles(ev: V5Evidence, task: str) -> list[tuple[dict, dict]]:
    rows = ev.accepted[ev.accepted["Task"] == task].to_dict("records")
    out = []
    for r in rows:
        try:
            vals = {k: V.parse(s) for k, s in (r.get("Candidates") or {}).items()}
        except InputError:
            continue
        if len(vals) == 5 and all(isinstance(v, V.Scalar) and v.is_angle for v in vals.values()):
            out.append((r, {k: float(v.value) for k, v in vals.items()}))
    if not out:
        raise NotCheckable(f"no {task} rows with five angle candidates")
    return out


def circular_gap(a: float, b: float) -> float:
    """The angle between two headings in degrees, in [0, 180]."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


@measure("v5_angle_separation")
def _v5_angle_separation(ev: V5Evidence, *, task: str) -> Measured:
    rows = _angles(ev, task)
    gap = min(circular_gap(a, b) for _, v in rows for a, b in itertools.combinations(v.values(), 2))
    return Measured(round(gap, 6), f"{gap:.2f}°", f"smallest circular gap between two candidates of one row, "
                                                   f"{len(rows)} rows")


@measure("v5_angle_outside")
def _v5_angle_outside(ev: V5Evidence, *, task: str) -> Measured:
    rows = _angles(ev, task)
    n = sum(1 for _, v in rows for x in v.values() if not -180.0 <= x < 180.0)
    return Measured(n, f"{n}", f"candidates outside [-180°, 180°) among {5 * len(rows)}")


@measure("v5_rank_balance")
def _v5_rank_balance(ev: V5Evidence, *, task: str) -> Measured:
    per: dict[str, Counter] = {}
    for r, v in _angles(ev, task):
        order = sorted(v, key=lambda k: (v[k], k))
        per.setdefault(r["Source"], Counter())[order.index(r["Answer"]) + 1] += 1
    spread = max(max(c.get(k, 0) for k in range(1, 6)) - min(c.get(k, 0) for k in range(1, 6)) for c in per.values())
    text = "; ".join(f"{s}: " + "/".join(str(c.get(k, 0)) for k in range(1, 6)) for s, c in sorted(per.items()))
    return Measured(spread, f"spread {spread} ({text})", "rows per signed-value rank of the answer (1 = smallest), "
                                                         "per source")


@measure("v5_letter_balance")
def _v5_letter_balance(ev: V5Evidence, *, task: str) -> Measured:
    a = ev.accepted[ev.accepted["Task"] == task]["Answer"]
    c = Counter(a)
    dist = max(abs(c.get(k, 0) - len(a) / 5) for k in LETTERS)
    text = " ".join(f"{k}={c.get(k, 0)}" for k in LETTERS)
    return Measured(round(dist, 6), f"{dist:g} ({text})", "answer letters of the task's rows")


def _verdicts(ev: V5Evidence) -> Counter:
    return Counter(r.get("verification_verdict") for r in ev.excluded)


@measure("v5_exclusion_class")
def _v5_exclusion_class(ev: V5Evidence, *, cls: str) -> Measured:
    n = sum(k for v, k in _verdicts(ev).items() if verdict_class(v) == cls)
    return Measured(n, f"{n}", "by verification verdict, the rule of the exclusion glossary "
                               "(resti_lib/report/v5_exclusions.yaml)")


@measure("v5_verdicts_present")
def _v5_verdicts_present(ev: V5Evidence, *, verdicts: list[str]) -> Measured:
    c = _verdicts(ev)
    present = [v for v in verdicts if c.get(v)]
    return Measured(len(present), f"{len(present)} of {len(verdicts)}",
                    "; ".join(f"{v.removeprefix('exclusion_confirmed_')} {c.get(v, 0)}" for v in verdicts))


@measure("v5_verify_failing")
def _v5_verify_failing(ev: V5Evidence, *, checks: list[str]) -> Measured:
    if ev.validation is None:
        raise NotCheckable("no resti verify result of v5 (notebook 00)")
    got = ev.validation.get("checks") or {}
    failing = {k: int(got[k].get("n_failing", 0)) for k in checks if k in got and got[k].get("status") == "fail"}
    rows = set()
    for k in failing:
        rows.update(map(str, got[k].get("failing") or []))
    how = "resti verify: " + (", ".join(f"{k} {n}" for k, n in failing.items()) if failing else
                              "every one of " + ", ".join(k for k in checks if k in got) + " passes")
    return Measured(len(rows), f"{len(rows)}", how)


# ---------------------------------------------------------------------- measurements of our run

def _table(ev: RunEvidence, name: str) -> pd.DataFrame:
    t = ev.tables.get(name)
    if t is None:
        raise NotCheckable(f"table {name} not written")
    return t


def _total_row(t: pd.DataFrame, column: str) -> int:
    if column not in t.columns:
        return 0
    tot = t[t["task"] == "Total"]
    return int(tot[column].iloc[0]) if len(tot) else int(t[column].sum())


@measure("legacy_key_detail")
def _legacy_key_detail(ev: RunEvidence, *, row: str) -> Measured:
    t = _table(ev, "key_detail_breakdown")
    pick = {"paper": lambda c: c.startswith("mismatches, the ReSTI report's"),
            "structured": lambda c: c.startswith("structured"), "scalar": lambda c: c.startswith("scalar")}[row]
    n = int(t[t["cause"].map(pick)]["rows"].iloc[0])
    return Measured(n, f"{n:,}", "key–detail breakdown (the ReSTI report's definition)")


@measure("legacy_defect")
def _legacy_defect(ev: RunEvidence, *, table: str, defect: str) -> Measured:
    n = _total_row(_table(ev, table), defect)
    return Measured(n, f"{n:,}", f"rows with the {defect} defect ({table})")


@measure("legacy_verdict")
def _legacy_verdict(ev: RunEvidence, *, verdict: str) -> Measured:
    n = _total_row(_table(ev, "verdicts"), verdict)
    return Measured(n, f"{n:,}", f"{verdict} rows of our audit")


@measure("legacy_pooled_attack")
def _legacy_pooled_attack(ev: RunEvidence, *, attack: str) -> Measured:
    t = _table(ev, "legacy_scalar_attacks")
    r = t[t["attack"] == attack]
    if r.empty:
        raise NotCheckable(f"attack {attack} did not run on the legacy scalar rows")
    r = r.iloc[0]
    acc = 100.0 * float(r["hits"]) / float(r["picked"])
    return Measured(acc, f"{acc:.1f}% ({float(r['hits']):g}/{int(r['picked'])})", "pooled over the legacy scalar rows")


@measure("legacy_pooled_rows")
def _legacy_pooled_rows(ev: RunEvidence) -> Measured:
    t = _table(ev, "legacy_scalar_attacks")
    n = int(t["rows"].max()) if len(t) else 0
    return Measured(n, f"{n:,}", "legacy rows with five scalar candidates")


@measure("legacy_defect_reports")
def _legacy_defect_reports(ev: RunEvidence) -> Measured:
    n = int(_table(ev, "defect_categories")["reports"].sum())
    return Measured(n, f"{n:,}", "defect reports in the six categories")


# ----------------------------------------------------------------------------------- judging

def judge(claim: Claim, m: Measured) -> str:
    """``reproduced`` when the measured figure equals the report's (``compare``, ``decimals``)."""
    want, got = claim.value, m.value
    if isinstance(want, list):  # [hits, rows]
        return REPRODUCED if isinstance(got, tuple) and abs(got[0] - want[0]) < 1e-9 and got[1] == want[1] \
            else NOT_REPRODUCED
    if claim.decimals is not None:
        got = round(float(got), claim.decimals)
    ok = {"equal": lambda: abs(float(got) - float(want)) < 1e-9, "at_least": lambda: float(got) >= float(want) - 1e-9,
          "at_most": lambda: float(got) <= float(want) + 1e-9}[claim.compare]()
    return REPRODUCED if ok else NOT_REPRODUCED


def _row(c: Claim, measured: str, status: str, how: str) -> dict:
    return {"id": c.id, "section": c.section, "claim": c.claim, "ReSTI report": c.paper, "measured": measured,
            "status": status, "how": how}


def _evaluate(claims, ev) -> list[dict]:
    out = []
    for c in claims:
        args = {("cls" if k == "class" else k): v for k, v in c.args.items()}
        try:
            m = MEASURES[c.measure](ev, **args)
        except NotCheckable as e:
            out.append(_row(c, "", NOT_CHECKABLE, str(e)))
            continue
        out.append(_row(c, m.text, judge(c, m), m.how))
    return out


def v5_leaks(attacks: pd.DataFrame | None) -> list[dict]:
    """Per task, the strongest Holm-significant blind attack of v5 pooled over sources, which the ReSTI
    report does not mention (it reports v5's options at chance): the strongest rule (an attack a reader
    can state, e.g. the letter order) first, the learned attackers beside it."""
    if attacks is None or len(attacks) == 0:
        return []
    t = attacks[(attacks["source"] == "ALL") & (attacks["significant"].astype(str) == "True")]
    out = []
    for task, g in t.groupby("task", sort=False):
        g = g.sort_values(["accuracy", "hits"], ascending=False, kind="stable")
        learned = g["family"].astype(str).str.startswith("learned")
        rules, models = g[~learned], g[learned]
        b = (rules if len(rules) else g).iloc[0]
        how = f"{b['attack']} ({b['family']})"
        if len(rules) and len(models):
            m = models.iloc[0]
            how += f"; learned: {m['attack']} {_hits(float(m['hits']), int(m['picked']))}"
        out.append({"id": f"leak:{task}", "section": "not in the report", "claim": f"{task}: a blind reader beats chance",
                    "ReSTI report": "not mentioned (chance)", "measured": _hits(float(b["hits"]), int(b["picked"])),
                    "status": LEAK, "how": how + f"; {len(g)} Holm-significant attack(s) in this task (resti attack "
                                                 "on v5)"})
    return out


def v5_claims(accepted: pd.DataFrame | None, excluded: list[dict] | None, *, attacks: pd.DataFrame | None = None,
              validation: dict | None = None, why_not: str | None = None) -> pd.DataFrame:
    """The claims that need ReSTI v5, measured on it (``why_not``: v5 is not available, and why), and
    the leaks of v5 the report does not mention."""
    claims = [c for c in load_claims() if c.needs == "v5"]
    if why_not or accepted is None:
        rows = [_row(c, "", NOT_CHECKABLE, why_not or "no ReSTI v5 release") for c in claims]
    else:
        ev = V5Evidence(accepted, list(excluded or []), attacks, validation)
        rows = _evaluate(claims, ev) + v5_leaks(attacks)
    return pd.DataFrame(rows, columns=COLUMNS)


def legacy_claims(tables: dict[str, pd.DataFrame], *, real: bool) -> pd.DataFrame:
    """The claims that need the real legacy benchmark, measured from our run's ``tables`` when the input
    is ``real``; on synthetic input they are not checkable here, the synthetic figure shown in ``how``.
    Then the claims that need data that is not here."""
    ev = RunEvidence(tables, real)
    rows = []
    for r in _evaluate([c for c in load_claims() if c.needs == "legacy"], ev):
        if not real:
            synthetic = f"; on this run's synthetic legacy benchmark: {r['measured']}" if r["measured"] else ""
            r = {**r, "measured": "", "status": NOT_CHECKABLE,
                 "how": "needs the real STI-Bench legacy benchmark (the input is the synthetic mini-world)" + synthetic}
        rows.append(r)
    rows += [_row(c, "", NOT_CHECKABLE, c.args.get("why", "")) for c in load_claims() if c.needs == "none"]
    return pd.DataFrame(rows, columns=COLUMNS)


def panel(*frames: pd.DataFrame | None) -> pd.DataFrame:
    """The claim tables as one panel, in the order of ``paper_claims.yaml`` (leaks after the claims)."""
    order = {c.id: i for i, c in enumerate(load_claims())}
    df = pd.concat([f for f in frames if f is not None and len(f)], ignore_index=True) if any(
        f is not None and len(f) for f in frames) else pd.DataFrame(columns=COLUMNS)
    df = df.assign(_o=df["id"].map(lambda i: order.get(i, len(order))))
    return df.sort_values("_o", kind="stable").drop(columns="_o").reset_index(drop=True)


def paper_split() -> dict[str, int]:
    """The report's recoverable / structural split of the v5 exclusions, from its claims."""
    return {c.args["class"]: int(c.value) for c in load_claims() if c.measure == "v5_exclusion_class"}


def status_counts(df: pd.DataFrame) -> dict[str, int]:
    c = Counter(df["status"]) if len(df) else Counter()
    return {s: int(c.get(s, 0)) for s in STATUSES}
