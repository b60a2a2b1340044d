"""The main job (``make report`` / ``resti run``): notebooks in order, then the report index.

``params/default.yaml`` lists the stages; each stage is a notebook with its own params file.
Keys of ``default.yaml`` that a notebook's ``parameters`` cell declares are passed to it too, so
source roots and the legacy path are stated once.

Stages run in waves (stages of one wave in parallel). A stage whose notebook, code, params,
inputs and upstream stages are unchanged since it last ran, and whose output files are intact, is
skipped (:mod:`resti_lib.run.stages`); ``force=True`` reruns everything. ``only`` runs the named stages
and then every stage downstream of them that became stale, and names the stale stages it left.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .. import paths
from ..errors import InputError, OutputError
from .notebooks import NotebookError, load_params, notebook_parameters, run_notebook
from .plan import closure, downstream, main_config, match_only, notebook_of, plan, stage_params

REPORT = "report"  # the index page: a last stage of its own, run by this process


def _generator_stamp(seed: int) -> str:
    """sha256 of the generator's source files and the seed: a world made by other code is stale."""
    import hashlib

    h = hashlib.sha256(f"seed={seed}".encode())
    for f in sorted((paths.ROOT / "resti_lib" / "synth").glob("*.py")):
        h.update(f.name.encode() + f.read_bytes())
    return h.hexdigest()


def ensure_world(cfg: dict) -> Path | None:
    """Generate the embedded mini-world when the params point at it and it is absent or was made by
    another version of the generator (or another seed).

    The orchestrator only *creates input data* here; the audit itself never imports the generator
    nor reads its manifest.
    """
    world = cfg.get("world_dir")
    if not world:
        return None
    from ..io.files import atomic_write_bytes
    from ..io.lock import folder_lock

    world = paths.resolve(world)
    seed = cfg.get("world_seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise InputError(f"world_seed {seed!r} is not an integer", field="world_seed")
    stamp_file = world / ".generator_stamp"
    stamp = _generator_stamp(seed)
    # under the world's lock: a second run waits for a world being generated, then finds it ready
    with folder_lock(world, what="mini-world folder", wait=True):
        if (world / "world.json").is_file() and (world / "legacy" / "qa.parquet").is_file() \
                and stamp_file.is_file() and stamp_file.read_text() == stamp:
            return world
        from ..synth import generate

        t0 = time.perf_counter()
        print(f"resti run: generating the mini-world in {world} ...", file=sys.stderr)
        generate(world, seed=seed)
        atomic_write_bytes(stamp_file, stamp.encode("ascii"))
        print(f"resti run: mini-world ready ({time.perf_counter() - t0:.1f}s)", file=sys.stderr)
    return world


INPUT_KEYS = ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root", "video_map")
STAGE_INPUT_KEYS = ("release_path", "reference_release")


def output_placement_problem(cfg: dict, stages: list[dict], common: dict) -> str | None:
    """Why an output folder of the run (``output_dir``, or a stage's ``release_dir``, ``table_dir``, ...)
    is, holds or lies inside an input folder (the legacy file's folder, a source root, a release the
    stages read), checked before any stage runs. The mini-world the run generates (``world_dir``) may
    lie inside ``output_dir``, as in the default layout; nothing may be written inside it."""
    from ..release.publish import input_problem
    from .runinfo import OUTPUT_KEYS

    def real(p):
        return Path(os.path.realpath(paths.resolve(p)))

    world = real(cfg["world_dir"]) if cfg.get("world_dir") else None
    inputs = []
    for k in INPUT_KEYS:
        if cfg.get(k):
            inputs.append((k, real(cfg[k]).parent if k in ("legacy_benchmark", "video_map") else real(cfg[k])))
    outputs = [("output_dir", real(cfg.get("output_dir") or "outputs"))]
    for s in stages:
        own = load_params(s["params"]) if s.get("params") else {}
        for k in OUTPUT_KEYS:
            if own.get(k):
                outputs.append((f"{s['notebook']}: {k}", real(own[k])))
        for k in STAGE_INPUT_KEYS:
            v = own.get(k, common.get(k))
            if v and "${SHARED}" not in str(v):
                inputs.append((f"{s['notebook']}: {k}", real(v)))
    for okey, out in outputs:
        for ikey, inp in inputs:
            generated = world is not None and (inp == world or world in inp.parents)
            if generated:  # our own mini-world: the output folder may hold it, never be or lie inside it
                if out == world or world in out.parents:
                    return f"{okey} {out} lies inside the generated mini-world {world}"
                continue
            why = input_problem(out, [inp])
            if why:
                return f"{okey} {out} {why} ({ikey}): refused before any stage ran"
    return None


def missing_inputs(cfg: dict) -> list[str]:
    """Every input path of the params that does not exist (one message for all of them)."""
    from ..sources.context import check_real_params

    return check_real_params(cfg)


class Planner:
    """Keys of the stages of one run (params, inputs, code, upstream keys) against the state."""

    def __init__(self, cfg: dict, common: dict, out_root: Path, needs: dict[str, list[str]]):
        from .runinfo import package_versions
        from .stages import Fingerprints, State, code_digest

        self.cfg, self.common, self.out_root, self.needs = cfg, common, out_root, needs
        self.state = State(out_root)
        self.fp = Fingerprints(out_root)
        self.code = code_digest()
        self.env = package_versions()
        world = cfg.get("world_dir")
        self.exclude = [out_root / ".resti"] + ([paths.resolve(world)] if world else [])
        self._prepared: dict[str, tuple[Path, dict, bool]] = {}

    def prepared(self, stage: dict) -> tuple[Path, dict, bool]:
        """Notebook, merged parameters, and whether it takes the run context."""
        n = stage["notebook"]
        if n not in self._prepared:
            nb = notebook_of(stage)
            declared = self.state.declared(nb)
            if declared is None:
                declared = list(notebook_parameters(nb))
                self.state.remember_declared(nb, declared)
            nb, params = stage_params(stage, self.common, declared=set(declared))
            self._prepared[n] = (nb, params, "run_context" in declared)
        return self._prepared[n]

    def context(self, stage: dict, params: dict) -> dict:
        """The run block for a stage that takes it: the params of the stages it is made from as
        they last ran (so a stage left stale by ``--only`` is stated with the params of its outputs)."""
        from .runinfo import run_context, stage_params_digest

        digests = {}
        for n in closure(stage["notebook"], self.needs):
            recorded = (self.state.stages.get(n) or {}).get("own_params")
            digests[n] = recorded or stage_params_digest(self.prepared_by_name(n)[1])
        digests[stage["notebook"]] = stage_params_digest(params)
        return run_context(self.cfg, digests, reference=params.get("reference_release"))

    def prepared_by_name(self, name: str) -> tuple[Path, dict, bool]:
        return self.prepared(next(s for s in self.cfg.get("stages") or [] if s["notebook"] == name))

    def key(self, stage: dict, needs: list[str]):
        """The stage's key and the parameters it runs with."""
        from .runinfo import stage_params_digest
        from .stages import stage_key

        nb, params, takes_context = self.prepared(stage)
        run_params = {**params, "run_context": self.context(stage, params)} if takes_context else params
        k = stage_key(nb, run_params, code=self.code, env=self.env, inputs=self.fp.inputs(params),
                      needs={n: self.state.key_of(n) for n in needs})
        k.own_params = stage_params_digest(params)
        return k, run_params

    def scan(self) -> dict:
        from .stages import scan

        return scan(self.out_root, self.exclude)


def _report_key(planner: Planner) -> str:
    from .runinfo import digest

    return digest({"code": planner.code,
                   "stages": {n: s.get("key") for n, s in sorted(planner.state.stages.items()) if n != REPORT}})


def run(params_file: str | Path | None = None, *, only=None, jobs: int | None = None, force: bool = False,
        baseline: bool = False) -> int:
    """Run the stages of ``params_file`` that are stale (all with ``force``); returns an exit code.

    Bad params raise :class:`InputError` (one line, naming the file and field). The whole run holds
    the lock of its output folder (:func:`resti_lib.io.lock.run_lock`): a second run on the same output
    folder stops at once with a :class:`~resti_lib.errors.BusyError`. ``baseline``: this run becomes the
    baseline the report's What changed section compares later runs with (:mod:`resti_lib.report.changes`;
    default: the first run of the output folder).
    """
    from ..io.lock import run_lock

    t_start = time.perf_counter()
    params_file = params_file or paths.PARAMS / "default.yaml"
    cfg = main_config(params_file)
    placement = output_placement_problem(cfg, cfg.get("stages") or [], {k: v for k, v in cfg.items() if k != "stages"})
    if placement:  # before the lock, the world or anything else is made
        raise OutputError(placement, file=paths.resolve(params_file), field="output_dir")
    with run_lock(paths.resolve(cfg.get("output_dir") or "outputs")):
        return _run(cfg, only=only, jobs=jobs, force=force, t_start=t_start, baseline=baseline)


RUN_PARAMS = "run_params.json"  # under <output_dir>/.resti: the params each stage last ran with


def _record_params(planner: Planner, stages: dict, ran: list[str]) -> dict:
    """The params every stage (on-demand stages aside) last ran with, output locations left out, and
    the params files the package reads itself: what the What changed section compares. Stages that
    ran now are recorded with their params; the others keep the record of their last run (a stage
    never recorded: its current params)."""
    import yaml

    from ..io.files import atomic_write_bytes
    from .runinfo import OUTPUT_KEYS
    from .stages import LIBRARY_PARAMS

    path = planner.out_root / ".resti" / RUN_PARAMS
    old = _read_json(path) or {}
    recorded = old.get("stages") or {}
    out: dict = {"stages": {}, "library": {}}
    for n, s in stages.items():
        if s.get("on_demand"):
            continue
        if n in ran or n not in recorded:
            params = planner.prepared(s)[1]
            recorded[n] = {k: v for k, v in params.items() if k not in OUTPUT_KEYS and k != "run_context"}
        out["stages"][n] = recorded[n]
    for name in LIBRARY_PARAMS:
        f = paths.ROOT / name
        out["library"][name] = yaml.safe_load(f.read_text(encoding="utf-8")) if f.exists() else None
    import json

    atomic_write_bytes(path, (json.dumps(out, indent=1, sort_keys=True, ensure_ascii=False, default=str) + "\n").encode())
    return out


def _run(cfg: dict, *, only, jobs: int | None, force: bool, t_start: float, baseline: bool = False) -> int:
    from tqdm.auto import tqdm

    stages = cfg.get("stages") or []
    common = {k: v for k, v in cfg.items() if k != "stages"}
    selected = match_only(stages, list(only)) if only is not None else None
    ensure_world(cfg)
    problems = missing_inputs(cfg) if "legacy_benchmark" in cfg else []
    if problems:
        print("resti run: the params name inputs that are missing or wrong:\n  - " + "\n  - ".join(problems),
              file=sys.stderr)
        return 2
    waves, needs = plan(stages, common)
    if selected is None:
        candidates = [s["notebook"] for s in stages if not s.get("on_demand")]
        forced = set(candidates) if force else set()
    else:
        after = downstream(selected, needs, stages)
        candidates = selected + after
        forced = set(candidates) if force else set(selected)
    by_name = {s["notebook"]: s for s in stages}
    out_root = paths.resolve(cfg.get("output_dir") or "outputs")
    planner = Planner(cfg, common, out_root, needs)
    jobs = jobs or cfg.get("jobs") or os.cpu_count() or 1
    nb_dir, html_dir = out_root / "notebooks", out_root / "report" / "notebooks"
    ran, skipped, seconds = [], [], {}
    bar = None
    try:
        for w in sorted({waves[n] for n in candidates}):
            wave = [n for n in candidates if waves[n] == w]
            current = planner.scan()
            keys, run_params, todo = {}, {}, []
            for n in wave:
                keys[n], run_params[n] = planner.key(by_name[n], needs[n])
                reason = "forced" if n in forced else planner.state.stale_reason(n, keys[n], current)
                (todo if reason else skipped).append(n)
            if not todo:
                continue
            todo = longest_first(todo, planner.state)
            if bar is None:
                bar = tqdm(total=len(todo), desc="notebooks", unit="nb", file=sys.stderr)
            else:
                bar.total += len(todo)
                bar.refresh()
            failed = None
            with ThreadPoolExecutor(max_workers=max(1, min(jobs, len(todo)))) as ex:
                futures = {n: ex.submit(run_notebook, planner.prepared(by_name[n])[0], run_params[n], out_dir=nb_dir,
                                        html_dir=html_dir) for n in todo}
                for n, f in futures.items():
                    try:
                        r = f.result()
                    except NotebookError as e:
                        failed = failed or e
                        planner.state.forget(n)
                        continue
                    seconds[n] = r.seconds
                    ran.append(n)
                    bar.update(1)
                    bar.set_postfix_str(f"{r.name} {r.seconds:.1f}s")
            done = [n for n in todo if n in seconds]
            planner.state.record(done, {n: {**keys[n].parts(), "own_params": keys[n].own_params} for n in done},
                                 seconds, current, planner.scan())
            planner.fp.forget_outputs()
            planner.state.save()
            if failed:
                raise failed
    except NotebookError as e:
        if bar is not None:
            bar.close()
        said = getattr(e, "input_message", None)
        if said:  # the same one line as outside a notebook, and the same exit code
            print(f"resti run: input error: {said}", file=sys.stderr)
            return 2
        print(f"resti run: {e}", file=sys.stderr)
        return 1
    if bar is not None:
        bar.close()
    from ..report.changes import update as update_changes

    changed = update_changes(out_root, _record_params(planner, by_name, ran), rebaseline=baseline)
    index = _write_report(planner, out_root, force=force or bool(ran) or baseline)
    _warn_stale(planner, stages, candidates, needs)
    print(summary(out_root, ran=ran, skipped=skipped, seconds=time.perf_counter() - t_start, index=index,
                  changed=changed))
    return 0


def _write_report(planner: Planner, out_root: Path, *, force: bool) -> Path:
    """The index page, rewritten when a stage ran or when it is stale."""
    index = out_root / "report" / "index.html"
    key = _report_key(planner)
    old = planner.state.stages.get(REPORT, {})
    current = planner.scan()
    if not force and index.exists() and old.get("key") == key and not planner.state.changed_products(REPORT, current):
        return index
    from ..report.index import write_index

    write_index(out_root, products=set(planner.state.data["products"]))
    planner.state.record([REPORT], {REPORT: {"key": key}}, {}, current, planner.scan())
    planner.state.save()
    return index


def _warn_stale(planner: Planner, stages: list[dict], candidates: list[str], needs: dict) -> None:
    """Name the stages left stale by ``--only`` (their outputs predate their params or code)."""
    current = planner.scan()
    left = []
    for s in stages:
        n = s["notebook"]
        if n in candidates or s.get("on_demand"):
            continue
        reason = planner.state.stale_reason(n, planner.key(s, needs[n])[0], current)
        if reason:
            left.append(f"{n} ({reason})")
    if left:
        print("resti run: warning: stale stages not run: " + "; ".join(left)
              + ". `resti run` (or `make report`) refreshes them and what depends on them.", file=sys.stderr)


# ------------------------------------------------------------------------------------ summary

def _read_json(p: Path):
    import json

    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _significant(csv_path: Path) -> list[dict]:
    import csv

    if not csv_path.exists():
        return []
    with open(csv_path, encoding="utf-8", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r.get("significant") == "True"]
    return sorted(rows, key=lambda r: -float(r.get("accuracy") or 0))


def _rel_to_cwd(p: Path) -> str:
    try:
        return os.path.relpath(p)
    except ValueError:
        return str(p)


def longest_first(todo: list[str], state) -> list[str]:
    """A wave's stages, the ones that took longest when last run first (list scheduling: a long
    stage started last would hold the wave open alone); stages never run keep their params order,
    ahead of the rest."""
    last = {n: (state.stages.get(n) or {}).get("seconds") for n in todo}
    return sorted(todo, key=lambda n: (last[n] is not None, -(last[n] or 0.0)))


def summary(out_root: Path, *, ran: list[str], skipped: list[str], seconds: float, index: Path,
            changed: dict | None = None) -> str:
    """The closing lines of a run: what ran, the release counts, verify, significant attacks, what
    changed against the baseline (and its warnings) and where to look next."""
    lines = [f"resti run: {len(ran)} stage(s) run, {len(skipped)} up to date, {seconds:.1f} s"
             + (f" ({', '.join(ran)})" if ran else "")]
    rel = out_root / "release"
    meta = _read_json(rel / "release.json")
    val = _read_json(rel / "validation.json")
    if meta:
        c = meta.get("counts", {})
        inp = (meta.get("run") or {}).get("input") or {}
        kind = (f"synthetic mini-world, seed {inp.get('seed')}" if inp.get("synthetic")
                else "real data" if inp else "input not recorded")
        lines.append(f"  release: {c.get('original', 0):,} legacy rows ({kind}) -> {c.get('accepted', 0):,} "
                     f"accepted + {c.get('excluded', 0):,} excluded; verify "
                     + ("PASSED" if val and val.get("passed") else "FAILED" if val else "not run"))
    from ..report.index import reference_audit, release_attack_counts

    tables = out_root / "tables"
    ours = release_attack_counts(out_root)
    if ours is not None:
        lines.append(f"  blind attacks on our release: {ours.sentence()}; `resti attack {_rel_to_cwd(rel)}` prints "
                     "the same")
    ref = reference_audit(out_root)
    if ref is not None:
        v, att = ref["verify"], ref["attacks"]
        failing = ", ".join(f"{k} {n}" for k, n in v["failing"].items())
        sig = _significant(out_root / "answer_interface" / f"attacks_{ref['label']}.csv")
        top = "; ".join(f"{r['task']}/{r['source']} {r['attack']} {float(r['accuracy']):.1%}" for r in sig[:4])
        lines.append(f"  reference release {ref['release']}: resti verify "
                     + ("PASSED" if v["passed"] else f"FAILED ({failing} rows)")
                     + f"; blind attacks: {att['sentence']}" + (f", strongest: {top}" if top else ""))
    if changed:
        names = ", ".join(f"{p['param']} {p['before']} -> {p['after']}" for p in changed["params"][:4])
        lines.append(f"  what changed against the baseline run: {names}; {changed['rows_changed']} rows changed"
                     + (f"; {len(changed['warnings'])} warning(s) in the report's What changed section"
                        if changed["warnings"] else ""))
        lines += [f"    warning: {w['text']}" for w in changed["warnings"]]
    lines.append(f"  report: {_rel_to_cwd(index)}  (release: {_rel_to_cwd(rel)}, tables: {_rel_to_cwd(tables)})")
    return "\n".join(lines)
