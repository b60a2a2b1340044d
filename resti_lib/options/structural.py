"""What options cannot fix: blind leaks that live in the answers or the questions, with their size.

The option stage makes the five candidates of a row exchangeable given what the question states.
Some leaks survive any choice of candidates, because they are properties of the answers themselves
or of other fields a blind reader sees. :func:`structural_leaks` measures each of them per
(task, source): the rows it affects and the accuracy a blind rule exploiting it reaches on those
rows at least (``accuracy_on_affected``; chance is 1/5), so the attack tables can be read
against it:

* ``floor_concentration`` — more answers fall inside a window narrower than the separation floor
  allows candidates to share than five exchangeable candidates can hold: of any answers inside a
  window holding at most ``m`` separated candidates, an attacker picking inside the window is right
  at least ``1/m`` of the time (the Waymo heading changes cluster within a degree of zero, while
  Orientation options must be 1 degree apart);
* ``rotation_repeat`` — Pose answers whose printed rotation is the premise's printed rotation
  (a car driving straight); printed rotations of the candidates must differ, so at most one
  candidate carries it;
* ``same_video_reveal`` — a Pose answer printed verbatim as the premise of another question of the
  same video; hidden only where the video has four other premises to use as distractors;
* ``zero_slot`` — exact zeros (stationary objects) and answers at the printing floor are one printed
  string each, which a row carries at most once: when more than a fifth of the rows of one kind of
  question (:func:`plan.slot_subgroup`: the quantity, of the camera or of an object, at an instant or
  over a window, all of which the question shows) answer it, that string is the answer in more than a
  fifth of the rows where it appears, whatever the options;
* ``repeated_answer`` — rows of one source sequence that ask the same thing and share the answer
  (the camera videos of one Waymo segment asking the ego heading change): options can make them
  share one candidate set, but a reader of one row's answer key knows the others';
* ``relation_floor`` — a row whose answer a related row of its recording gives (a heading change
  the turn sum of a trajectory description over its window, a dimension a box edge: see
  :mod:`resti_lib.options.follow`) where every candidate of that row predicts the answer to within
  half the separation floor: any other candidate is then at least half a floor from every
  prediction and the answer is the one nearest (a car driving straight: every trajectory candidate
  turns 0 degrees, and the heading change is within half a degree of 0);
* ``label_prior`` — the most frequent label of a categorical task;
* ``metadata`` — an answer that follows from the video name (the Waymo camera mount names the
  Spatial Relation label): the accuracy of the best camera -> label rule, leave one out.

:func:`evaluation_subset` chooses, without touching the release, the rows of a documented subset
under which the label prior, metadata, same-video and zero-slot attacks are at chance.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import values as V
from ..errors import InputError
from ..rng import stable_seed
from .checks import parse_row
from .observables import relation_parts
from .plan import dense_window, share_key, slot_answers, slot_subgroup_sizes, slot_subgroup_text
from .spec import Interface, angle_gap, scalar_gap, spec_of

CHANCE = 0.2
COLUMNS = ["task", "source", "leak", "n_rows", "rows_affected", "accuracy_on_affected", "detail", "remedy"]


def _specs(records: list[dict], iface: Interface) -> list:
    out = []
    for i, r in enumerate(records):
        try:
            out.append(spec_of(r, str(r.get("ReSTI ID") or i), iface=iface))
        except InputError:
            out.append(None)
    return out


def _floor_bound(values: np.ndarray, gaps: np.ndarray) -> tuple[float, str, int, int]:
    """The window of sorted answers with the largest ``share / m``, ``m`` the most separated
    candidates it can hold (width / floor + 1): (share / m, description, answers inside, m)."""
    order = np.argsort(values)
    x, g = values[order], gaps[order]
    n = len(x)
    best, where, inside, slots = 0.0, "", 0, 1
    j = 0
    for i in range(n):
        j = max(j, i)
        while j + 1 < n and x[j + 1] - x[i] < 4 * g[j + 1]:
            j += 1
        for k in range(i, j + 1):
            m = int(math.floor((x[k] - x[i]) / max(g[k], 1e-12) + 1e-9)) + 1
            share = (k - i + 1) / n
            if share / m > best:
                best, inside, slots = share / m, k - i + 1, m
                where = f"{k - i + 1} of {n} answers within [{x[i]:g}, {x[k]:g}], where {m} separated candidate(s) fit"
    return best, where, inside, slots


Leak = tuple  # (leak, rows affected, accuracy on them, detail, remedy)


def _floor_and_zero_leaks(sp: list, params: dict) -> list[Leak]:
    """Scalars and angles: answers crowded inside a window narrower than the separation floor, and
    exact zeros above a fifth of a quantity's answers."""
    out = []
    kind = sp[0].kind
    by_q: dict[str, list] = defaultdict(list)
    for s in sp:
        by_q[s.obs.quantity].append(s)
    for q, ss in sorted(by_q.items()):
        nonzero = [s for s in ss if kind == "angle" or s.value.value > 0]
        if kind == "angle":
            gaps = np.array([angle_gap(s, params) for s in nonzero])
        else:
            gaps = np.array([max(scalar_gap(s, params, s.value.value),
                                 params["separation"]["scalar"]["min_rel_gap"] * s.value.value) for s in nonzero])
        if len(nonzero) >= 5:
            bound, where, inside, slots = _floor_bound(np.array([s.value.value for s in nonzero], float), gaps)
            if bound > CHANCE and inside >= 5:
                out.append(("floor_concentration", inside, 1.0 / slots, f"{q}: {where}",
                            "none by options; re-contract the questions or accept and report"))
        if kind != "scalar":
            continue
        # a slot string is one per row: answering more than a fifth of the rows of its subgroup (the
        # kind of question a reader sees), it is the answer in more than a fifth of the rows carrying it
        size = slot_subgroup_sizes(ss)
        for (sub, _), idx in slot_answers(ss).items():
            n, zeros = size[sub], len(idx)
            if zeros / n > CHANCE:
                carriers = min(n, zeros + int(round(params["model"]["zero_slot_ratio"] * zeros)))
                out.append(("zero_slot", carriers, zeros / carriers,
                            f"{q} ({slot_subgroup_text(sub)}): {zeros} of {n} answers print {ss[idx[0]].detail}; "
                            f"that string appears in {carriers} rows",
                            "evaluation subset keeps such answers at one row in five of their kind of question"))
    return out


def _repeat_leaks(sp: list, n: int) -> list[Leak]:
    """Rows of one source sequence that ask one thing and share the answer."""
    reps: dict[tuple, int] = defaultdict(int)
    for s in sp:
        if s.kind != "label":
            reps[(s.obs.sequence, *share_key(s))] += 1
    repeated = sum(c for c in reps.values() if c > 1)
    if not repeated:
        return []
    return [("repeated_answer", repeated, 1.0,
             f"{repeated} of {n} rows share question and answer with another row of their source sequence "
             f"({sum(1 for c in reps.values() if c > 1)} groups)",
             "they share one candidate set; the evaluation subset keeps one row of each group")]


def _pose_leaks(sp: list, n: int) -> list[Leak]:
    """Pose answers that print the premise's rotation, and answers printed as a premise in their video."""
    out = []
    same = 0
    for s in sp:
        o = s.obs
        if o.premise is not None and o.premise_text is not None:
            pr = V.parse(o.premise_text)
            if np.array_equal(np.round(np.array(pr.R), 6), np.round(np.array(s.value.R), 6)):
                same += 1
    if same / n > CHANCE:
        out.append(("rotation_repeat", same, 1.0,
                    f"{same} of {n} answers print the premise's rotation; candidates' printed rotations must differ",
                    "none by options (print rotations at more decimals in the question contract)"))
    acc, revealed = 0.0, 0
    for s, printers, others in premise_reveals(sp):
        revealed += 1
        acc += 1.0 if s.rid in printers else 1.0 / (1 + min(4, others))
    if revealed:
        out.append(("same_video_reveal", revealed, acc / revealed,
                    f"{revealed} of {n} answers are printed as a premise in the same video (their own or another "
                    "question's)", "evaluation subset keeps one question of each revealing pair"))
    return out


def premise_reveals(specs: list):
    """``(spec, printers, others)`` for each Pose answer printed as the premise of a question of its
    video (its own or another's; every printer counted, none overwritten): the ids of the questions
    that print it, and how many other premises of the video could serve as distractors."""
    premises: dict[str, dict] = defaultdict(lambda: defaultdict(set))
    for s in specs:
        if s is not None and s.kind == "pose" and s.obs.premise_text:
            premises[s.obs.video][V.parse(s.obs.premise_text).key()].add(s.rid)
    for s in specs:
        if s is None or s.kind != "pose":
            continue
        prem = premises.get(s.obs.video, {})
        key = s.value.key()
        if prem.get(key):
            own = V.parse(s.obs.premise_text).key() if s.obs.premise_text else None
            yield s, prem[key], len([k for k in prem if k not in (key, own)])


def _label_leaks(sp: list, n: int) -> list[Leak]:
    """Categorical answers: the most frequent label, and the label the video name's camera predicts."""
    out = []
    lab, top = Counter(s.detail for s in sp).most_common(1)[0]
    if top / n > CHANCE:
        out.append(("label_prior", n, top / n, f"{top} of {n} answers are {lab!r}",
                    "evaluation subset balances the labels"))
    cams = [(s.obs.camera, s.detail) for s in sp if s.obs.camera is not None]
    if len(cams) >= 5:
        by_cam: dict = defaultdict(Counter)
        for cam, label in cams:
            by_cam[cam][label] += 1
        hits = 0
        for cam, label in cams:  # leave one out: the majority label of the other rows of the camera
            cnt = by_cam[cam].copy()
            cnt[label] -= 1
            best = cnt.most_common(1)[0] if sum(cnt.values()) else (None, 0)
            hits += best[0] == label
        if hits / len(cams) > CHANCE:
            out.append(("metadata", len(cams), hits / len(cams),
                        f"the camera number in the video name predicts the label in {hits} of {len(cams)} rows",
                        "evaluation subset leaves out cells whose label follows from the video name"))
    return out


def relation_forced(records: list[dict], specs: list, params: dict) -> dict[int, str]:
    """Rows whose answer every candidate of a related row of the same recording predicts to within
    half the row's separation floor (``relation_floor``, module docstring): index -> detail."""
    from .follow import FOLLOWS, find_link

    drivers: dict[str, list[int]] = defaultdict(list)
    for i, s in enumerate(specs):
        if s is not None and s.kind in ("box", "trajectory", "scalar"):
            drivers[s.obs.sequence].append(i)
    out = {}
    for i, f in enumerate(specs):
        if f is None or f.kind not in ("scalar", "angle") or f.obs.quantity not in FOLLOWS:
            continue
        sib = [specs[j] for j in drivers.get(f.obs.sequence, []) if j != i]
        link = find_link(f, sib, params.get("follow") or {}) if sib else None
        if link is None:
            continue
        j = next(k for k in drivers[f.obs.sequence] if specs[k].rid == link.driver)
        cands = records[j].get("Candidates") if isinstance(records[j].get("Candidates"), dict) else {}
        r = link.residual(f, specs[j].value)
        try:  # what each candidate of the related row predicts (the answer's own residual taken off)
            images = [link.image(f, specs[j].value, V.parse(t), -r) for t in cands.values()] if r is not None else []
        except InputError:
            continue
        if not images or any(x is None for x in images):
            continue
        a = float(f.value.value)
        if f.kind == "angle":
            half = 0.5 * angle_gap(f, params)
            far = max(abs((a - x + 180.0) % 360.0 - 180.0) for x in images)
        else:
            half = 0.5 * max(scalar_gap(f, params, a), params["separation"]["scalar"]["min_rel_gap"] * a)
            far = max(abs(a - x) for x in images)
        if far < half:
            out[i] = f"{link.relation} of {link.driver}: every candidate within {far:.3g} of the answer"
    return out


def structural_leaks(records: list[dict], iface: Interface) -> pd.DataFrame:
    """One row per (task, source, leak) that options cannot remove (see the module docstring), under
    the answer interface the options are built with."""
    params = iface.options
    specs = _specs(records, iface)
    cells: dict[tuple, list[int]] = defaultdict(list)
    for i, r in enumerate(records):
        cells[(str(r.get("Task")), str(r.get("Source")))].append(i)
    forced = relation_forced(records, specs, params)
    out = []
    for (task, source), idx in sorted(cells.items()):
        sp = [specs[i] for i in idx if specs[i] is not None]
        n = len(idx)
        if not sp:
            continue
        kind = sp[0].kind
        found = _floor_and_zero_leaks(sp, params) if kind in ("scalar", "angle") else []
        found += _repeat_leaks(sp, n)
        found += _pose_leaks(sp, n) if kind == "pose" else []
        found += _label_leaks(sp, n) if kind == "label" else []
        hit = [i for i in idx if i in forced]
        if hit:
            found.append(("relation_floor", len(hit), 1.0,
                          f"{len(hit)} of {n} rows: a related row's every candidate predicts the answer to within half "
                          f"the separation floor (e.g. {forced[hit[0]]})",
                          "none by this row's options; the evaluation subset leaves them out"))
        for leak, affected, acc, detail, remedy in found:
            out.append({"task": task, "source": source, "leak": leak, "n_rows": n, "rows_affected": int(affected),
                        "accuracy_on_affected": round(float(acc), 4), "detail": detail, "remedy": remedy})
    return pd.DataFrame(out, columns=COLUMNS)


@dataclass
class _Selection:
    """What the steps of :func:`evaluation_subset` share: the rows, their specs and ids, the rows
    dropped so far (id -> reason), the seeded RNG, the interface and the structural leaks."""

    records: list
    specs: list
    rid: list
    drop: dict
    rng: np.random.Generator
    iface: Interface
    leaks: pd.DataFrame


def _drop_metadata(c: _Selection) -> None:
    """Cells whose label follows from the video name (the metadata leak at 90% or more)."""
    records, rid, drop, leaks = c.records, c.rid, c.drop, c.leaks
    meta_cells = {(t, s) for t, s, lk, b in zip(leaks["task"], leaks["source"], leaks["leak"],
                                                 leaks["accuracy_on_affected"]) if lk == "metadata" and b >= 0.9}
    for i, r in enumerate(records):
        if (r.get("Task"), r.get("Source")) in meta_cells:
            drop[rid[i]] = "metadata"


def _drop_converse_pairs(c: _Selection) -> None:
    """Of converse relation questions of one video and time (A relative to B, B relative to A), one is
    kept."""
    records, specs, rid, drop = c.records, c.specs, c.rid, c.drop
    seen_pairs: set = set()
    for i, s in enumerate(specs):
        if s is None or s.kind != "label" or rid[i] in drop:
            continue
        parts = relation_parts(records[i].get("Question"))
        if parts is None:
            continue
        pair = (s.obs.video, s.obs.time_start, frozenset(parts))
        if pair in seen_pairs:
            drop[rid[i]] = "converse_pair"
        seen_pairs.add(pair)


def _balance_labels(c: _Selection) -> None:
    """Categorical answers balanced to the rarest label per task and source."""
    specs, rid, drop, rng = c.specs, c.rid, c.drop, c.rng
    groups: dict[tuple, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
    for i, s in enumerate(specs):
        if s is not None and s.kind == "label" and rid[i] not in drop:
            groups[(s.task, s.source)][s.detail].append(i)
    for _, by in sorted(groups.items()):
        m = min(len(v) for v in by.values())
        for lab in sorted(by):
            ids = by[lab]
            keep = set(rng.permutation(len(ids))[:m].tolist())
            for j, i in enumerate(ids):
                if j not in keep:
                    drop[rid[i]] = "label_balance"


def _drop_repeated_answers(c: _Selection) -> None:
    """One row of each group of rows of a sequence that ask the same thing with the same answer."""
    specs, rid, drop = c.specs, c.rid, c.drop
    seen_rep: set = set()
    for i, sp_ in enumerate(specs):
        if sp_ is None or sp_.kind == "label" or rid[i] in drop:
            continue
        k = (sp_.obs.sequence, *share_key(sp_))
        if k in seen_rep:
            drop[rid[i]] = "repeated_answer"
        seen_rep.add(k)


def _drop_pose_reveals(c: _Selection) -> None:
    """Pose answers equal to their own premise, and answers printed as the premise of another question
    of their video."""
    specs, rid, drop = c.specs, c.rid, c.drop
    # question prints the other's answer as its premise (every such pair counted, none overwritten)
    by_premise: dict[tuple, list[int]] = defaultdict(list)
    for i, s in enumerate(specs):
        if s is not None and s.kind == "pose" and s.obs.premise_text:
            try:
                by_premise[(s.obs.video, V.parse(s.obs.premise_text).key())].append(i)
            except InputError:
                continue
    for i, s in enumerate(specs):
        if s is None or s.kind != "pose" or rid[i] in drop:
            continue
        printers = [j for j in by_premise.get((s.obs.video, s.value.key()), []) if rid[j] not in drop]
        if i in printers:
            drop[rid[i]] = "answer_is_premise"
        elif printers:
            drop[rid[i]] = "same_video_reveal"


def _drop_keyed_reveals(c: _Selection) -> None:
    """Rows whose answer a sibling row's answer gives through physics (a rate over a window, a path
    length, a box edge, a turn sum, a pose on the camera's track, a converse relation): no option design
    hides that from a reader who knows the sibling's key, so one row of each such pair is left out. The
    keyed attacks of :mod:`resti_lib.options.attacks.relation` name the pairs: per attack and recording
    the first row they reveal is kept (its partner's answer revealed it) and the others dropped, then
    the attacks run again on what is kept, until they reveal nothing."""
    from .attacks import parse_rows, run_picks, select

    names = [n for n in select("keyed") if n.startswith("keyed_")]
    for _ in range(6):
        kept = [i for i in range(len(c.records)) if c.rid[i] not in c.drop and c.specs[i] is not None]
        if not kept:
            return
        recs = [c.records[i] for i in kept]
        picks = run_picks(parse_rows(recs), names, records=recs, iface=c.iface)
        if picks.empty:
            return
        hits = picks[(picks["tied"] == 1) & (picks["hit"] >= 1.0)]
        if hits.empty:
            return
        index = {str(c.rid[i]): i for i in kept}
        first: set = set()
        dropped = 0
        for name, rid_ in zip(hits["attack"], hits["rid"].astype(str)):
            i = index.get(rid_)
            if i is None or c.rid[i] in c.drop:
                continue
            key = (name, c.specs[i].obs.sequence)
            if key not in first:
                first.add(key)
                continue
            c.drop[c.rid[i]] = "keyed_reveal"
            dropped += 1
        if not dropped:
            return


def _drop_floor_forced(c: _Selection) -> None:
    """Angles inside a window narrower than the separation floor that holds more than a fifth of their
    cell hold its one candidate (``floor_forced``); every other row whose candidates touch that window
    goes too (``floor_window``). The choice is then a symmetric function of each row's candidate set,
    so the answer stays one of five in the rows kept: dropping only the window's answers left a
    subset where its candidate was never right, and keeping some of them left the rows beside the
    window (candidates a floor apart around a small turn) telling where the answer sits."""
    specs, rid, drop, iface = c.specs, c.rid, c.drop, c.iface
    cells_a: dict[tuple, list[int]] = defaultdict(list)
    for i, s in enumerate(specs):
        if s is not None and s.kind == "angle" and rid[i] not in drop:
            cells_a[(s.task, s.source)].append(i)
    for _, ids in sorted(cells_a.items()):
        vals = np.array([specs[i].value.value for i in ids])
        win = dense_window(vals, angle_gap(specs[ids[0]], iface.options))
        if win is None:
            continue
        lo, hi, _ = win
        for i, x in zip(ids, vals):
            if lo - 1e-9 <= x <= hi + 1e-9:
                drop[rid[i]] = "floor_forced"
            elif any(lo - 1e-9 <= float(v.value) <= hi + 1e-9
                     for v in parse_row(c.records[i], rid[i], iface).values.values()):
                drop[rid[i]] = "floor_window"


def _drop_relation_forced(c: _Selection) -> None:
    """Rows whose answer every candidate of a related row predicts to within half the floor."""
    kept = [i for i in range(len(c.records)) if c.rid[i] not in c.drop]
    forced = relation_forced([c.records[i] for i in kept], [c.specs[i] for i in kept], c.iface.options)
    for k in forced:
        c.drop[c.rid[kept[k]]] = "relation_floor"


def _cap_zero_answers(c: _Selection) -> None:
    """Slot answers (exact zeros, answers at the printing floor: :func:`plan.slot_answers`) at most one
    in five of their group."""
    specs, rid, drop, rng = c.specs, c.rid, c.drop, c.rng
    zgroups: dict[tuple, list[int]] = defaultdict(list)
    for i, s in enumerate(specs):
        if s is not None and s.kind == "scalar" and rid[i] not in drop:
            zgroups[(s.task, s.source, s.obs.quantity)].append(i)
    for _, ids in sorted(zgroups.items()):
        group = [specs[i] for i in ids]
        size = slot_subgroup_sizes(group)
        for (sub, _), js in slot_answers(group).items():
            zeros = sorted(ids[j] for j in js)
            allow = (size[sub] - len(zeros)) // 4  # one in five of the rows of its kind of question
            if len(zeros) > allow:
                pick = set(rng.permutation(len(zeros))[:allow].tolist())
                for j, i in enumerate(zeros):
                    if j not in pick:
                        drop[rid[i]] = "zero_slot"


#: The steps of :func:`evaluation_subset`, in order (each sees the rows the earlier ones kept).
SUBSET_STEPS = (_drop_metadata, _drop_converse_pairs, _balance_labels, _drop_repeated_answers, _drop_pose_reveals,
                _drop_keyed_reveals, _drop_floor_forced, _drop_relation_forced, _cap_zero_answers)


def evaluation_subset(records: list[dict], iface: Interface, leaks: pd.DataFrame | None = None, *, seed: int = 0
                      ) -> dict:
    """A documented subset of the rows (ids, every dropped row with its reason, and the rule) under
    which the structural leaks are at chance. The release itself is not changed. The steps run in
    :data:`SUBSET_STEPS` order, each on the rows the earlier ones kept."""
    leaks = structural_leaks(records, iface) if leaks is None else leaks
    rid = [str(r.get("ReSTI ID") or i) for i, r in enumerate(records)]
    drop: dict[str, str] = {}
    c = _Selection(records, _specs(records, iface), rid, drop, np.random.default_rng(stable_seed(seed, "evaluation_subset")),
                   iface, leaks)
    for step in SUBSET_STEPS:
        step(c)
    keep = [r for r in rid if r not in drop]
    return {
        "rule": ("Rows of the release kept for a blind-balanced evaluation: cells whose answer follows from the "
                 "video name are left out; of converse relation questions (A relative to B, B relative to A, one "
                 "video and time) one is kept; categorical answers are balanced to the rarest label per task and "
                 "source; of rows of one recording asking the same thing with the same answer, one is kept; a "
                 "Pose answer equal to its own premise, or printed as the premise of another question of its "
                 "video, is left out; of rows whose answer a sibling's answer gives through physics (a keyed "
                 "relation attack reveals it), one per recording and relation is kept; angles inside a window "
                 "narrower than the separation floor that holds more than a fifth of their cell (forced by the "
                 "floor) are left out with every row whose candidates touch that window; rows "
                 "whose answer every candidate of a related row predicts to within half the floor are left out; "
                 "slot answers (exact zeros, answers at the printing floor) are kept at "
                 "most one in five of their group. Selection seeded; the release is unchanged."),
        "seed": int(seed),
        "n_release": len(rid),
        "n_kept": len(keep),
        "dropped_by_reason": dict(sorted(Counter(drop.values()).items())),
        "dropped": [{"id": r, "reason": drop[r]} for r in rid if r in drop],
        "ids": keep,
    }


#: Reasons of :func:`evaluation_subset` that name a leak no option design hides (the row's answer
#: follows from the video name, a converse question, a sibling asking the same thing, a premise printed
#: in a question, a window under the separation floor (its answers and every row whose candidates touch
#: it), every candidate of a related row, or a zero string more frequent than one in five). The others
#: (``label_balance``, ``keyed_reveal``) trim what is left for a balanced evaluation and a reader of the
#: answer key.
STRUCTURAL_REASONS = ("metadata", "converse_pair", "repeated_answer", "answer_is_premise", "same_video_reveal",
                      "floor_forced", "floor_window", "relation_floor", "zero_slot")


def residual_ids(records: list[dict], iface: Interface, subset: dict) -> list[str]:
    """The ids of the rows of a release that no structural leak touches, for a reader of the whole
    file: every row but those its :func:`evaluation_subset` drops for a reason in
    :data:`STRUCTURAL_REASONS`, and every Pose answer printed as a premise of its video (the subset
    keeps one row of each revealing pair, which the other row's question still reveals in the file).
    An attack that beats chance on them (``attack_table(..., evaluate=residual_ids(...))``) found a
    leak of the options."""
    structural = {d["id"] for d in subset["dropped"] if d["reason"] in STRUCTURAL_REASONS}
    structural |= {s.rid for s, _, _ in premise_reveals(_specs(records, iface))}
    every = list(subset["ids"]) + [d["id"] for d in subset["dropped"]]
    return sorted(set(every) - structural)


__all__ = ["structural_leaks", "evaluation_subset", "residual_ids", "STRUCTURAL_REASONS", "COLUMNS"]
