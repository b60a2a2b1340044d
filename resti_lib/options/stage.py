"""The option stage: the five candidates of every accepted row, built once.

Used where the release is assembled (:func:`resti_lib.release.assemble.write_release`) and by ``resti
reoption`` — the same code, so what the report audits is what ships. Input: accepted rows in the
ReSTI schema (their ``Answer Detail`` is the answer; any existing candidates are ignored except the
label set of a categorical task) and, optionally, what each task knows beyond the row
(:class:`~resti_lib.options.spec.OptionSpec` extras). Output: the same rows with ``Candidates``
and ``Answer`` set, and one evidence record per row.

How a row's candidates are drawn (see :mod:`resti_lib.options.population`): the answers of its
group (task, source, quantity, unit) define a distribution *conditioned on what the question
states* — a distance is modelled as a rate over the question's window, a size relative to the
sizes of its subject's class, a pose as a motion from the premise pose over the window, a box's
centre, edge lengths and heading jointly (their correlation kept) — and the five candidates are
exchangeable draws from it, one of which is the answer (its own answer left out of the model).
Every candidate is printed from its own exact value by :mod:`resti_lib.values`, the way the answer
was printed; rotations start from an exact rotation that prints as the answer's matrix, so nothing
invariant under the perturbation can differ in its last digit.

Constraints, symmetric in the five candidates (a set that breaks one is redrawn whole, so the
answer stays exchangeable): pairwise separation (no two candidates within the task's adjudication
rule of each other, orientation options at least 1 degree apart, boxes and poses separated in
centre or translation, rotation and size) and physical possibility given the question (the implied
speed of a distance over its window, acceleration, sizes, depths). When the draws cannot meet the
constraints the spread widens in steps (recorded in the evidence).

Letters are balanced per task by a schedule. The answer's signed-value rank among the five is not
scheduled: it follows from the exchangeable draw (an extreme answer is more often the extreme
candidate, as any of five exchangeable values would be), so it is uniform over the rows without
tying an answer to a rank its value makes unlikely.

Exact zeros (a stationary object) and ``no significant movement`` are fixed slots: that string is
placed in every row whose answer it is and in ``zero_slot_ratio`` times as many other rows of the
group, so it is the answer in about one row in five where it appears.
Rows of one video that ask for the same answer share one candidate set, so another question of the
same video cannot reveal it; a Pose answer that another question of the same video prints as its
premise gets, where it can, other premise poses of that video as distractors.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict

import numpy as np
import pandas as pd

from .. import LETTERS
from .. import values as V
from ..errors import InputError, OptionError
from ..rng import row_rng, stable_seed
from .follow import FOLLOWS, box_edge_map, find_box_links, find_link, follow_box, follow_strings, grid_offsets, residual_offsets
from .kinds import builder_for
from .plan import ONE_D, GroupModel, Reject, RowPlan, constrained_schedule, couple_key, group_key, reprint, share_key, signed_rank
from .population import FieldModel, knn_ladder
from .spec import (
    Interface,
    OptionSpec,
    spec_of,
)

#: quantities whose rows other rows may follow (:data:`.follow.FOLLOWS`)
DRIVER_QUANTITIES = frozenset(q for qs, _, _ in FOLLOWS.values() for q in qs)


class Stage:
    """Plans and builds the options of a set of accepted rows (see the module docstring); the
    group fits and candidate draws of each answer kind are its builder's (:mod:`resti_lib.options.kinds`)."""

    def __init__(self, records: list[dict], *, iface: Interface, seed: int = 0, extras: dict | None = None,
                 peers: list[dict] | None = None, peer_iface: Interface | None = None):
        self.records = records
        self.seed = int(seed)
        self.iface = iface
        self.params = iface.options
        self.model = self.params["model"]
        extras = extras or {}
        self.plans: list[RowPlan] = []
        for i, r in enumerate(records):
            rid = str(r.get("ReSTI ID") or r.get("Legacy Row Key") or i)
            self.plans.append(RowPlan(spec_of(r, rid, extras.get(rid), iface=iface)))
        if len({p.rid for p in self.plans}) != len(self.plans):
            dup = [k for k, n in Counter(p.rid for p in self.plans).items() if n > 1]
            raise InputError(f"row ids are not unique, e.g. {dup[:3]}", field="ReSTI ID")
        self.by_id = {p.rid: p for p in self.plans}
        self.index = {p.rid: i for i, p in enumerate(self.plans)}
        # rows of other tasks whose options are already built (a task run after its drivers' runs):
        # followed, never drawn or shipped here
        self.peers: dict[str, tuple] = {}
        for i, r in enumerate(peers or []):
            rid = str(r.get("ReSTI ID") or f"peer-{i}")
            if rid in self.by_id or not isinstance(r.get("Candidates"), dict):
                continue
            try:
                self.peers[rid] = (spec_of(r, rid, None, iface=peer_iface or iface),
                                   [str(x) for x in r["Candidates"].values()])
            except InputError:
                continue
        self.groups: dict[str, GroupModel] = {}
        self.cur_draw = None
        self.last_draw = None
        self.free_draw = False  # the last widening tier (see _build_row)
        self.strings: dict[str, list[str]] = {}  # the five candidate strings of each row built
        self.reveals: dict = {}
        self.s_factors: dict = {}
        # the rows of each recording that other rows may follow, the dimension rows each box matches
        # (its edges follow them), and from those which box edge a dimension question asks per source
        # (class evidence for sizes)
        self.drivers: dict[str, list[OptionSpec]] = defaultdict(list)
        for spec in [p.spec for p in self.plans] + [sp for sp, _ in self.peers.values()]:
            if spec.obs.quantity in DRIVER_QUANTITIES:
                self.drivers[spec.obs.sequence].append(spec)
        follow = self.params.get("follow") or {}
        self.box_links = {p.rid: find_box_links(p.spec, self.drivers.get(p.spec.obs.sequence, []), follow)
                          for p in self.plans if p.spec.kind == "box"}
        self.edge_map = box_edge_map(self.box_links.values(),
                                     {**{p.rid: p.spec for p in self.plans}, **{r: sp for r, (sp, _) in self.peers.items()}})
        self._plan()

    # -------------------------------------------------------------------- planning
    def _plan(self) -> None:
        by_group: dict[str, list[RowPlan]] = defaultdict(list)
        for p in self.plans:
            p.group = group_key(p.spec)
            by_group[p.group].append(p)
        # a group too small to model pools with the other sources of its task (offsets per source)
        small = int(self.model.get("min_group", 8))
        for g in sorted(by_group):
            ps = by_group[g]
            if ps[0].spec.kind in ("scalar", "angle") and len(ps) < small:
                pooled = f"{ps[0].spec.task}|*|{ps[0].spec.unit}|{g.split('|', 3)[-1]}"
                for p in ps:
                    p.group = pooled
                by_group[pooled].extend(ps)
                del by_group[g]
        for g, ps in sorted(by_group.items()):
            kind = ps[0].spec.kind
            self.groups[g] = builder_for(kind).fit(self, g, ps)
        self._share_sets()
        self._links()
        for task in sorted({p.spec.task for p in self.plans}):
            ids = {p.rid: set(LETTERS) for p in self.plans if p.spec.task == task}
            sched = constrained_schedule(ids, list(LETTERS), seed=self.seed, group=f"letters|{task}")
            for rid, L in sched.items():
                self.by_id[rid].letter = L

    def _share_sets(self) -> None:
        """Rows that ask the same thing and have the same answer share one candidate set: the
        camera videos of one recording (their ego answers are equal), the same object asked in two
        scenes. Otherwise the answer, repeated with fresh distractors, is the one value two rows'
        options have in common."""
        first: dict[tuple, str] = {}
        for p in self.plans:
            key = share_key(p.spec)
            if key in first and p.spec.kind != "label":
                p.share_with = first[key]
            else:
                first.setdefault(key, p.rid)
        # rows of one recording asking the same quantity over the same window with answers closer
        # than the separation floor: their candidate sets are translates of one set (each by the
        # difference of the answers), so comparing them singles out no candidate
        bases: dict[tuple, list[RowPlan]] = defaultdict(list)
        for p in self.plans:
            if p.share_with is not None or p.answer_is_fixed or p.fixed or p.spec.kind not in ONE_D:
                continue
            kb = builder_for(p.spec.kind)
            key = couple_key(p.spec)
            base = next((b for b in bases[key] if kb.near(self, b, p)), None)
            if base is not None:
                p.couple_with = base.rid
            else:
                bases[key].append(p)

    def _links(self) -> None:
        """Rows whose candidate set follows a related row of another task (:mod:`.follow`): a row
        that draws its own set (not shared, coupled or fixed) and a driver of its recording — a row
        of this stage or an already built peer — whose answer relates to its answer."""
        follow = self.params.get("follow") or {}
        drivers = self.drivers
        for p in self.plans:  # a coupled row follows its driver where its translate fails the row's checks
            if p.share_with is not None or p.fixed or p.answer_is_fixed:
                continue
            if p.spec.obs.quantity in FOLLOWS and drivers.get(p.spec.obs.sequence):
                if p.spec.kind == "box":
                    p.box_links = self.box_links[p.rid]
                else:
                    p.link = find_link(p.spec, drivers[p.spec.obs.sequence], follow)
        # the residuals of the links (the follower's answer against what its driver's answer gives), per
        # relation and source: drawn for distractors whose exact images coincide
        self.residuals: dict[tuple, list[tuple[str, float]]] = defaultdict(list)
        specs = {**{p.rid: p.spec for p in self.plans}, **{rid: sp for rid, (sp, _) in self.peers.items()}}
        for p in self.plans:
            if p.link is not None:
                r = p.link.residual(p.spec, specs[p.link.driver].value)
                if r is not None:
                    self.residuals[(p.link.relation, p.spec.source)].append((p.spec.obs.sequence, r))
        depth: dict[str, int] = {}

        def depth_of(rid: str, seen: frozenset = frozenset()) -> int:
            if rid in depth:
                return depth[rid]
            p = self.by_id.get(rid)
            if p is None or rid in seen:  # a peer, or a loop (none by construction)
                return 0
            bases = [b for b in (p.share_with, p.couple_with, p.link.driver if p.link is not None else None)
                     if b is not None] + [lk.driver for lk in p.box_links]
            depth[rid] = max((1 + depth_of(b, seen | {rid}) for b in bases), default=0)
            return depth[rid]

        self.order = sorted(range(len(self.plans)), key=lambda i: (depth_of(self.plans[i].rid), i))

    def _driver(self, rid: str) -> tuple[OptionSpec, list[str]] | None:
        """A driver's spec and five candidate strings (a row of this stage once built, or a peer)."""
        if rid in self.peers:
            return self.peers[rid]
        if rid in self.strings:
            return self.by_id[rid].spec, self.strings[rid]
        return None

    # -------------------------------------------------------------------- building
    def fit_fields(self, plans: list, B, H, W, **kw) -> FieldModel:
        """The population model of one group's answers (``B``, half cells ``H``, covariates ``W``) with the
        model params: bandwidth neighbours (``knn``, chosen up to ``max_knn`` by how well the other
        recordings predict each recording's answers; ``echo``: see :meth:`echo_spec`), copula shrinkage,
        the smallest group; each row's distractors drawn without its recording's answers (the recording:
        the row's source sequence)."""
        return FieldModel.fit([p.rid for p in plans], B, H, W, knn=int(self.model["knn"]),
                              max_knn=int(self.model.get("max_knn") or 0), shrink=self.model["copula_shrink"],
                              min_rows=int(self.model["min_group"]), groups=[p.spec.obs.sequence for p in plans],
                              **kw)

    def echo_spec(self, lattice=None, offset=None, printed=None, fields=None) -> dict | None:
        """How each field's bandwidth of a group is widened against the echo
        (:func:`resti_lib.options.population.echo_balanced`): the neighbour counts tried (``knn``, 1.5 ``knn``,
        ... up to ``model.echo_knn``) and the draw simulated (the spread ``model.s``, the group's ``lattice``,
        each row's ``offset`` back to the printed scale and ``printed``, the values a reader sees); ``fields``:
        the fields read (None: all; the others keep the likelihood's count); None when ``model.echo_knn`` is
        not above ``knn`` (the likelihood's count)."""
        k, top = int(self.model["knn"]), int(self.model.get("echo_knn") or 0)
        if top <= k:
            return None
        return {"ladder": knn_ladder(k, top), "s": float(self.model["s"]), "lattice": lattice,
                "offset": offset, "printed": printed, "fields": None if fields is None else sorted(fields)}

    def draw(self, gm: GroupModel, rid: str, cells: list, s: float, rng, bounds: list | None = None,
              **kw) -> np.ndarray:
        """Draw through the row's prepared model (kept for the row being built only: O(G) memory)."""
        key = (id(gm), rid, None if bounds is None else tuple(map(tuple, bounds)))
        if self.cur_draw is None or self.cur_draw[0] != key:
            self.cur_draw = (key, gm.fields.prepare(rid, bounds))
        rd = self.cur_draw[1]
        out = rd.draw(cells, s, rng, **kw)
        self.last_draw = rd
        return out

    def calibrate(self, *, sample: int = 60, rounds: int = 2) -> dict:
        """Per group, the within-set spread under which the kept candidate sets are as spread around
        their answer as the model's unconstrained sets are.

        Separation and plausibility constraints reject sets whose candidates crowd each other, so the
        sets kept are wider than the model's; their distractors would then be less typical than
        the answer. Each round builds a seeded sample of the group's rows and scales the spread ``s``
        by the root mean square distance from the answer (standardised scores) of everything drawn
        for those rows over that of the distractors kept — paired over the same answers, so their
        own spread cancels. Returns group -> spread factor.
        """
        out = {}
        by_group: dict[str, list[RowPlan]] = defaultdict(list)
        for p in self.plans:
            if p.spec.kind != "label" and not p.answer_is_fixed and p.share_with is None:
                by_group[p.group].append(p)
        for g, ps in sorted(by_group.items()):
            gm = self.groups[g]
            if gm.fields is None or len(ps) < 20:
                continue
            rng = np.random.default_rng(stable_seed(self.seed, "calibrate", g))
            pick = [ps[int(i)] for i in sorted(rng.permutation(len(ps))[:sample])]
            factor = 1.0
            for _ in range(rounds):
                gm.info["s_factor"] = factor
                drawn, kept = [], []
                for p in pick:
                    saved = dict(p.evidence)
                    try:
                        self._build_row(p, None, {}, calibrating=True)
                    except OptionError:
                        continue
                    finally:
                        p.evidence = saved
                    rd = self.last_draw
                    if rd is not None and rd.last_za is not None and rd.drawn:
                        za = np.asarray(rd.last_za).reshape(1, -1)
                        drawn.append(((np.concatenate(rd.drawn) - za) ** 2).ravel())
                        kept.append(((np.asarray(rd.last_z).reshape(-1, za.shape[1]) - za) ** 2).ravel())
                if len(kept) < 10:
                    break
                ratio = math.sqrt(float(np.mean(np.concatenate(drawn))) / max(float(np.mean(np.concatenate(kept))),
                                                                              1e-12))
                factor = float(np.clip(factor * ratio, 0.5, 1.0))
            gm.info["s_factor"] = factor
            out[g] = factor
        return out

    def build(self, progress: bool = False, on_failure: str = "raise") -> tuple[list[dict], pd.DataFrame, dict]:
        """Build every row; returns (rows, evidence, failed). ``on_failure``: ``raise`` stops at a
        row whose options cannot meet the constraints; ``skip`` leaves its candidates empty and
        names it in ``failed`` (rid -> problem), for the caller to exclude. The rows then pass the
        adversarial filter (:meth:`adversarial_filter`); its rounds are in ``evidence.attrs``."""
        failed: dict[str, str] = {}
        self.s_factors = self.calibrate()
        it = self.order
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(self.order, desc="options", unit="row", leave=False)
        self.reveals = self._reveals()
        built: dict[str, list[str]] = {}
        for i in it:  # drivers before the rows that follow them
            p, r = self.plans[i], self.records[i]
            strings = self._dependent(p, built)
            if strings is None:
                try:
                    strings = self._build_row(p, r, self.reveals)
                except OptionError as e:
                    if on_failure != "skip":
                        raise
                    failed[p.rid] = str(e)
                    continue
                built[p.rid] = strings
                strings = self._follow_box(p, strings)
            self.strings[p.rid] = strings
        log = self.adversarial_filter(built, failed)
        out, ev = [], []
        for p, r in zip(self.plans, self.records):
            if p.rid in failed:
                out.append(dict(r))
                continue
            strings = self.strings[p.rid]
            cands, letter = self._letter(p, strings)
            new = dict(r)
            new["Candidates"] = cands
            new["Answer"] = letter
            out.append(new)
            ev.append({"rid": p.rid, "task": p.spec.task, "source": p.spec.source, "kind": p.spec.kind,
                       "group": p.group, "letter": letter, "rank": signed_rank(p, strings),
                       "fixed": ",".join(p.fixed), "answer_is_fixed": p.answer_is_fixed,
                       "s_factor": self.groups[p.group].info.get("s_factor", 1.0) if p.group in self.groups else None,
                       **p.evidence})
        frame = pd.DataFrame(ev)
        frame.attrs["adversarial"] = log
        return out, frame, failed

    def _dependent(self, p: RowPlan, built: dict) -> list[str] | None:
        """A row's candidates when they follow another row's: the same set (shared) or its translate
        (coupled, when the translate meets the row's checks); None when the row draws its own."""
        # the base's set as shipped (drawn, or following another row: self.strings holds both)
        if p.share_with is not None and p.share_with in self.strings:
            p.evidence.update({"shared_with": p.share_with})
            return list(self.strings[p.share_with])
        if p.couple_with is not None and p.couple_with in self.strings:
            coupled = builder_for(p.spec.kind).translate(self, self.by_id[p.couple_with], p,
                                                         self.strings[p.couple_with])
            if coupled is not None and self._coupled_ok(p, coupled):
                p.evidence.update({"coupled_with": p.couple_with})
                return coupled
        if p.link is not None:
            followed = self._follow(p)
            if followed is not None:
                return followed
            p.evidence.pop("follows", None)
        return None

    def _follow(self, p: RowPlan) -> list[str] | None:
        """The row's candidates as images of its driver's (:mod:`.follow`): exact images first; where
        two coincide or a check fails, images moved by residuals drawn from the other recordings'
        links (a bounded number of draws). None when no set meets the row's checks."""
        drv = self._driver(p.link.driver)
        if drv is None:
            return None
        dspec, dstrings = drv
        own = p.link.residual(p.spec, dspec.value)
        pool = [r for seq, r in self.residuals.get((p.link.relation, p.spec.source), [])
                if seq != p.spec.obs.sequence]
        rng = row_rng(self.seed, p.rid, "follow")
        sep = self.params["separation"]
        step = 1.1 * (float(sep["angle"]["min_sep_deg"]) if p.link.additive
                      else math.log1p(float(sep["scalar"]["min_rel_gap"])))
        tries = [("exact", None)] + [("grid", o) for o in grid_offsets(step, rng, 20)]
        if own is not None:
            tries += [("residual", o) for o in residual_offsets(own, pool, rng, 40)]
        for how, offsets in tries:
            followed = follow_strings(p.link, p.spec, dspec, dstrings, offsets)
            if followed is not None and self._coupled_ok(p, followed):
                p.evidence.update({"follows": p.link.driver, "relation": p.link.relation, "follow_offsets": how})
                return followed
        return None

    def _follow_box(self, p: RowPlan, own: list[str]) -> list[str]:
        """A box's own draw with the edges its dimension rows ask following their candidates
        (:func:`.follow.follow_box`), when that set meets the row's checks; else its own draw."""
        if not p.box_links:
            return own
        drivers = {lk.driver: d for lk in p.box_links if (d := self._driver(lk.driver)) is not None}
        out = follow_box(p.box_links, p.spec, drivers, own, self.groups[p.group].info.get("decimals") or {})
        if out is not None and self._coupled_ok(p, out):
            p.evidence["follows_dimensions"] = [lk.driver for lk in p.box_links]
            return out
        p.evidence.pop("follows_dimensions", None)
        return own

    def _base(self, rid: str) -> str:
        """The row whose draw a row's candidates come from (itself when it draws its own)."""
        ev = self.by_id[rid].evidence  # what the row's set was made from (a peer is never drawn here)
        for b in (ev.get("shared_with"), ev.get("coupled_with"), ev.get("follows")):
            if b is not None and b in self.by_id and b != rid:
                return self._base(b)
        return rid

    # -------------------------------------------------------------------- adversarial filtering
    def adversarial_filter(self, built: dict, failed: dict) -> list[dict]:
        """Check the drawn options with the strongest blind discriminators (``params/options.yaml``
        ``adversarial.attacks``: learned out of fold by recording, and the priors learned on the other
        half of the recordings) on the rows no structural leak touches
        (:func:`resti_lib.options.structural.residual_ids`; every row stays readable): in every
        task/source cell where one of them is significant (the suite's exact test,
        :func:`.attacks.scoring.cell_tests`; Holm over the cells at ``alpha``), the rows
        it identifies (its one pick is the answer) get their
        distractors drawn again (a new stream of their RNG; the letters stay); then the check runs
        again, at most ``rounds`` times (the work, and so the time, is bounded by the rounds, not by a
        clock: the same input gives the same bytes on any machine). A round that would redraw more than
        ``max_redrawn_share`` of the rows stops the filter (the draw itself then leaks, which redrawing
        cannot mend; the record says so).

        Redrawing the rows an attack got right leaves its misses, so a cell can look at chance while the
        generator still leaks. Each check after a redraw therefore also scores the rows drawn again
        by the last round on their own (a fresh sample of the generator, whatever picked them), in the
        cells that named them (Holm over those cells); where they are still significant, the filter
        stops with ``draw leaks`` and names the cells (``draw_leaks``): redrawing hides such a leak,
        it does not mend it. Returns one record per round."""
        from .attacks import parse_rows, run_picks
        from .attacks.scoring import cell_tests, holm
        from .structural import evaluation_subset, residual_ids

        def scored(picks: pd.DataFrame) -> pd.DataFrame:
            return cell_tests(picks, ["attack", "direction", "task", "source"])

        def named(cells: pd.DataFrame, keys) -> list[dict]:
            return [{"attack": a, "direction": d, "task": tk, "source": s, "hits": float(cells.loc[(a, d, tk, s), "hits"]),
                     "n": int(cells.loc[(a, d, tk, s), "n"])} for a, d, tk, s in sorted(keys)]

        af = self.params.get("adversarial") or {}
        rounds, alpha = int(af.get("rounds", 0)), float(af.get("alpha", 0.05))
        names = list(af.get("attacks") or [])
        share = float(af.get("max_redrawn_share", 0.5))
        log: list[dict] = []
        checked: dict[str, pd.DataFrame] = {}  # the last picks of each task
        dirty: set | None = None  # tasks with rows drawn again since their last check (None: all)
        fresh: set[str] = set()  # the rows the last round drew again
        named_last: set = set()  # the cells that named them
        for rnd in range(rounds):
            rows = []
            for p, r in zip(self.plans, self.records):
                if p.rid in failed or p.spec.kind == "label":
                    continue
                cands, letter = self._letter(p, self.strings[p.rid])
                rows.append({**r, "ReSTI ID": p.rid, "Candidates": cands, "Answer": letter})
            if not rows:
                break
            by_task: dict[str, list[dict]] = defaultdict(list)
            for r in rows:  # one task at a time: the cells are per task, and memory stays that of one task
                by_task[str(r.get("Task"))].append(r)
            for task, rs in sorted(by_task.items()):  # a task none of whose rows changed keeps its picks
                if dirty is None or task in dirty or task not in checked:
                    checked[task] = run_picks(parse_rows(rs), names, records=rs, iface=self.iface)
            frames = [checked[task] for task in sorted(by_task)]
            picks = pd.concat([f for f in frames if len(f)], ignore_index=True) if any(len(f) for f in frames) \
                else pd.DataFrame(columns=["pick", "rid"])
            # rows a structural leak touches are read, not scored: no draw hides their leak, and
            # redrawing them would only hide it from the check (resti attack --rows residual)
            residual = set(residual_ids(rows, self.iface, evaluation_subset(rows, self.iface, seed=self.seed)))
            picks = picks[picks["pick"].notna() & picks["rid"].astype(str).isin(residual)]
            if picks.empty:  # no attack picks on the rows it may score
                log.append({"round": rnd + 1, "rows_checked": len(residual), "cells_checked": 0,
                            "significant_cells": [], "stopped": "at chance"})
                break
            picks = picks.assign(direction=picks["direction"].fillna("").astype(str))
            # every task's rows pooled over its sources too (a leak can be too thin to see per source)
            picks = pd.concat([picks, picks.assign(source="ALL")], ignore_index=True)
            cells = scored(picks)
            significant = {k for k, sig in zip(cells.index, holm(cells["p"], alpha)) if sig}
            record = {"round": rnd + 1, "rows_checked": len(residual), "cells_checked": int(len(cells)),
                      "significant_cells": named(cells, significant)}
            if fresh and named_last:  # the rows drawn again last round, on their own
                again = scored(picks[picks["rid"].astype(str).isin(fresh)])
                again = again[again.index.isin(sorted(named_last))]
                leaks = {k for k, sig in zip(again.index, holm(again["p"], alpha)) if sig}
                record["redrawn_rows_checked"] = len(fresh)
                if leaks:
                    record.update({"draw_leaks": named(again, leaks), "stopped": "draw leaks"})
                    log.append(record)
                    break
            if not significant or rnd == rounds - 1:  # at chance, or the last check: nothing is redrawn after it
                record["stopped"] = "at chance" if not significant else "rounds"
                log.append(record)
                break
            sel = picks[[(a, d, tk, s) in significant
                         for a, d, tk, s in zip(picks["attack"], picks["direction"], picks["task"], picks["source"])]]
            identified = sorted(set(sel.loc[(sel["tied"] == 1) & (sel["hit"] >= 1.0), "rid"].astype(str)))
            if len(identified) > share * len(rows):
                record.update({"identified": len(identified), "redrawn": 0, "stopped": "max_redrawn_share"})
                log.append(record)
                break
            redrawn, changed = self._redraw(identified, built, failed, rnd + 1)
            dirty = {self.by_id[rid].spec.task for rid in changed}
            fresh, named_last = {str(r) for r in changed}, significant
            record.update({"identified": len(identified), "redrawn": redrawn})
            log.append(record)
            if not redrawn:
                record["stopped"] = "nothing to redraw"
                break
        return log

    def _redraw(self, rids: list[str], built: dict, failed: dict, rnd: int) -> tuple[int, set]:
        """Draw the named rows' distractors again (their base row when they follow one), then the rows
        that follow those (in build order). Returns how many rows were drawn again, and every row whose
        set changed."""
        bases = []
        for rid in rids:
            if rid not in self.by_id:
                continue
            base = self._base(rid)
            if base in built and base not in bases and not self.by_id[base].answer_is_fixed:
                bases.append(base)
        n = 0
        changed = set()
        for rid in bases:
            p = self.by_id[rid]
            try:
                strings = self._build_row(p, self.records[self.index[rid]], self.reveals, stream=f"adversarial-{rnd}")
            except OptionError:
                continue  # keeps the set it has (it meets every requirement)
            built[rid] = strings
            self.strings[rid] = self._follow_box(p, strings)
            p.evidence["adversarial_redrawn"] = rnd
            changed.add(rid)
            n += 1
        for i in self.order:  # rows that follow a redrawn row follow it again
            q = self.plans[i]
            if q.rid in failed or q.rid in changed:
                continue
            if q.rid in built:  # a box whose dimension rows were drawn again
                if {lk.driver for lk in q.box_links} & changed:
                    self.strings[q.rid] = self._follow_box(q, built[q.rid])
                    changed.add(q.rid)
                continue
            if {q.share_with, q.couple_with, q.evidence.get("follows")} & changed:
                again = self._dependent(q, built)
                if again is not None:
                    self.strings[q.rid] = again
                    changed.add(q.rid)
        return n, changed

    def _coupled_ok(self, p: RowPlan, strings: list[str]) -> bool:
        """A translated set meets the row's own requirements (the checks ``resti verify`` runs)."""
        from .checks import ROW_CHECKS, parse_row

        rec = {**self.records[self.index[p.rid]], "Candidates": dict(zip(LETTERS, strings)), "Answer": "E"}
        pr = parse_row(rec, p.rid, self.iface)
        return all(ROW_CHECKS[c](pr) is None for c in ("separation", "plausible_given_question", "format_consistency"))

    def _letter(self, p: RowPlan, strings: list[str]) -> tuple[dict, str]:
        """The answer at its scheduled letter; the others in a seeded random order."""
        ans = p.spec.detail
        others = [s for s in strings if s != ans]
        rng = row_rng(self.seed, p.rid, "letters")
        others = [others[int(i)] for i in rng.permutation(len(others))]
        cands = {}
        for L in LETTERS:
            cands[L] = ans if L == p.letter else others.pop(0)
        return cands, p.letter

    def _build_row(self, p: RowPlan, record: dict | None, reveals: dict, *, calibrating: bool = False,
                   stream: str = "options") -> list[str]:
        kind = p.spec.kind
        if kind == "label":
            return builder_for("label").build_label(self, p, record)
        gm = self.groups[p.group]
        kb = builder_for(kind)
        s0 = float(self.model["s"]) * gm.info.get("s_factor", 1.0)
        tries = int(self.model["max_tries"]) // (4 if calibrating else 1)
        if kind in ("scalar", "angle", "trajectory"):
            tries = max(2, tries // 16)  # each try is a batch of 32 sets
        rng = row_rng(self.seed, p.rid, "calibrate" if calibrating else stream)
        last = "no candidates drawn"
        # widening steps: a wider spread, then (relaxed) same-video premises no longer imposed
        # a last tier draws a scalar's distractors from its group's population without conditioning
        # on the answer's cell (exchangeable still; for answers repeated so often across recordings
        # that every conditioned draw lands on them)
        tiers = ((s0, True, False), (min(0.8, 1.5 * s0), True, False), (min(0.8, 1.5 * s0), False, False),
                 (0.9, False, False), (0.9, False, True))
        # what a builder may keep across the tries of this build (oned.drawn_rank: a target it can drop
        # for the last tier)
        p.scratch = {"tries_before_last_tier": tries * (len(tiers) - 1)}
        for tier, (s, strict, free) in enumerate(tiers):
            self.free_draw = free
            for attempt in range(tries):
                try:
                    strings = kb.build(self, p, gm, s, rng, strict, reveals)
                except Reject as e:
                    last = str(e)
                    continue
                p.evidence.update({"s": s, "tries": tier * tries + attempt + 1, "strict": strict,
                                   **({"population_draw": True} if free else {}),
                                   "widened": tier > 0})
                return strings
        raise OptionError(f"{p.rid} ({p.spec.task}, {p.spec.source}): no options under the constraints ({last})")

    # -------------------------------------------------------------------- same-video reveals
    def _reveals(self) -> dict:
        """Pose answers that another question of the same video prints as its premise: the other
        premise poses of the video that can serve as distractors (rid -> strings)."""
        premises: dict[str, dict] = defaultdict(dict)
        for p in self.plans:
            o = p.spec.obs
            if p.spec.kind == "pose" and o.premise_text:
                try:
                    premises[o.video][V.parse(o.premise_text).key()] = (p.rid, o.premise_text)
                except InputError:
                    continue
        out: dict[str, list[str]] = {}
        for p in self.plans:
            if p.spec.kind != "pose":
                continue
            prem = premises.get(p.spec.obs.video, {})
            key = p.spec.value.key()
            if key in prem and prem[key][0] != p.rid:
                own = p.spec.obs.premise_text
                others = sorted({txt for k, (r, txt) in prem.items() if k != key and txt != own})
                v: V.Pose = p.spec.value
                usable = [reprint(t, v) for t in others]
                out[p.rid] = [t for t in usable if t != p.spec.detail]
                p.evidence["same_video_reveal"] = {"revealed_by": prem[key][0], "other_premises": len(out[p.rid])}
        return out


def build_options(records: list[dict], *, iface: Interface, seed: int = 0, extras: dict | None = None,
                  progress: bool = False, on_failure: str = "raise",
                  peers: list[dict] | None = None,
                  peer_iface: Interface | None = None) -> tuple[list[dict], pd.DataFrame, dict]:
    """Candidates and letters for every row under the answer interface ``iface`` (the option params
    and each task's rule and question reader; see the module docstring); returns (rows, evidence,
    failed) — see :meth:`Stage.build`."""
    if not records:
        return [], pd.DataFrame(), {}
    st = Stage(records, iface=iface, seed=seed, extras=extras, peers=peers, peer_iface=peer_iface)
    return st.build(progress=progress, on_failure=on_failure)


__all__ = ["OptionError", "Stage", "build_options"]
