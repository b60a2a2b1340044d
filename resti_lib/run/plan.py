"""The stages of the main job: which notebooks run, with which params, in which wave, and which
stage needs which.

Every registered task is a stage of the first wave (its notebook, its params file beside the main
params file, else in ``params/``); ``params/default.yaml`` lists the other stages (the release and
report, the answer-interface audits) and may list a task's notebook to set its params or wave.
Each stage is a notebook with its own params file.
Keys of ``default.yaml`` that a notebook's ``parameters`` cell declares are passed to it too, so
source roots and the legacy path are stated once.
"""

from __future__ import annotations

from pathlib import Path

from .. import paths
from ..defaults import check_params, load
from ..errors import InputError
from .notebooks import load_params, notebook_parameters

TASK_WAVE = 1
STAGE_KEYS = frozenset({"notebook", "params", "wave", "needs", "on_demand", "wave_if_missing"})


def task_stages(params_file=None) -> list[dict]:
    """One stage per registered task, in notebook order: ``{notebook, params, wave, needs}``. The
    params file is ``<params_name>.yaml`` beside ``params_file`` when there is one, else in
    ``params/``. A task runs in wave 1, or after the tasks it follows (``Task.follows``: its
    candidate sets follow theirs), which it then needs."""
    from ..tasks import all_tasks

    here = paths.resolve(params_file).parent if params_file else paths.PARAMS
    tasks = {t.name: t for t in all_tasks()}
    depth: dict[str, int] = {}

    def depth_of(name: str, seen: tuple = ()) -> int:
        if name in seen:
            raise InputError(f"tasks follow each other in a loop: {' -> '.join((*seen, name))}", field="follows")
        if name not in depth:
            t = tasks[name]
            unknown = [x for x in t.follows if x not in tasks]
            if unknown:
                raise InputError(f"task {name!r} follows unregistered task(s) {unknown}", field="follows")
            depth[name] = max((1 + depth_of(x, (*seen, name)) for x in t.follows), default=0)
        return depth[name]

    out = []
    for t in sorted(tasks.values(), key=lambda t: t.notebook):
        own = here / f"{t.params_name}.yaml"
        out.append({"notebook": t.notebook, "params": str(own if own.is_file() else paths.PARAMS / own.name),
                    "wave": TASK_WAVE + depth_of(t.name), "needs": [tasks[x].notebook for x in t.follows]})
    return out


def main_config(params_file=None) -> dict:
    """The main job's params (default ``params/default.yaml``) with its full stage list: the task
    stages (:func:`task_stages`, unless the params list the notebook themselves), then the listed
    stages (checked first: :func:`check_stages`)."""
    params_file = params_file or paths.PARAMS / "default.yaml"
    cfg = load_params(params_file)
    schema = {k: v for k, v in load("default").items() if k != "stages"}
    check_params({k: v for k, v in cfg.items() if k != "stages"}, schema, file=paths.resolve(params_file),
                 what="main params")
    check_stages(cfg, params_file)
    listed = cfg.get("stages") or []
    if isinstance(listed, list):
        named = {s.get("notebook") for s in listed if isinstance(s, dict)}
        tasks = [s for s in task_stages(params_file) if s["notebook"] not in named]
        last = max((s["wave"] for s in tasks), default=TASK_WAVE)
        for i, s in enumerate(listed):  # a stage that reads every task's outputs runs after the last task wave
            if isinstance(s, dict) and s.get("needs") is None and not s.get("on_demand") \
                    and isinstance(s.get("wave"), int) and TASK_WAVE < s["wave"] <= last:
                raise InputError(f"stage {s.get('notebook')} runs in wave {s['wave']}, beside task stages (the tasks "
                                 f"that follow other tasks run up to wave {last}); give it wave {last + 1} or later",
                                 file=paths.resolve(params_file), row=f"stage {i}", field="wave")
        cfg["stages"] = tasks + listed
    return cfg


def check_stages(cfg: dict, params_file) -> None:
    """Every stage of the params names an existing notebook and a readable params file
    (:class:`InputError` naming the params file, the stage and the field)."""
    where = paths.resolve(params_file)
    stages = cfg.get("stages") or []
    if not isinstance(stages, list):
        raise InputError("stages must be a list of {notebook, params, wave}", file=where, field="stages")
    for i, st in enumerate(stages):
        if not isinstance(st, dict):
            raise InputError("a stage must be a mapping {notebook, params, wave}", file=where, row=f"stage {i}",
                             field="stages")
        name = st.get("notebook")
        if not isinstance(name, str) or not name or "/" in name or "\\" in name or name.startswith("."):
            raise InputError(f"notebook {name!r} is not a notebook name", file=where, row=f"stage {i}",
                             field="notebook")
        if not (paths.NOTEBOOKS / f"{name}.ipynb").is_file():
            known = sorted(p.stem for p in paths.NOTEBOOKS.glob("*.ipynb"))
            raise InputError(f"no notebook {name!r} in {paths.NOTEBOOKS} (known: {', '.join(known)})",
                             file=where, row=f"stage {i}", field="notebook")
        unknown = sorted(set(st) - STAGE_KEYS)
        if unknown:
            raise InputError(f"unknown stage field(s) {unknown}; a stage has {sorted(STAGE_KEYS)}", file=where,
                             row=f"stage {i}", field=str(unknown[0]))
        for key, ok, want in (("wave", lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
                               "an integer at least 0"),
                              ("needs", lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
                               "a list of stage names"),
                              ("on_demand", lambda v: isinstance(v, bool), "true or false"),
                              ("wave_if_missing", lambda v: isinstance(v, dict) and set(v) == {"param", "wave"}
                               and isinstance(v["wave"], int) and not isinstance(v["wave"], bool),
                               "{param, wave}")):
            if key in st and not ok(st[key]):
                raise InputError(f"{st[key]!r} is not {want}", file=where, row=f"stage {i}", field=key)
        if st.get("params") is not None:
            if not isinstance(st["params"], str):
                raise InputError(f"params {st['params']!r} is not a path", file=where, row=f"stage {i}",
                                 field="params")
            own = load_params(st["params"])
            check_params(own, declared_defaults(paths.NOTEBOOKS / f"{name}.ipynb"), file=paths.resolve(st["params"]),
                         what=f"params of stage {name}")


def declared_defaults(nb: Path) -> dict:
    """The parameters a notebook declares, with their default values (its ``parameters`` cell, which
    carries the YAML defaults): the schema of that stage's params."""
    import ast

    out = {}
    for name, d in notebook_parameters(nb).items():
        try:
            out[name] = ast.literal_eval(d["default"])
        except (ValueError, SyntaxError):
            out[name] = None
    return out


def notebook_of(stage: dict) -> Path:
    nb = paths.NOTEBOOKS / f"{stage['notebook']}.ipynb"
    if not nb.exists():
        known = ", ".join(sorted(p.stem for p in paths.NOTEBOOKS.glob("*.ipynb")))
        raise InputError(f"stage notebook {stage['notebook']!r} not found in {paths.NOTEBOOKS} (notebooks: {known})",
                         field="stages")
    return nb


def stage_params(stage: dict, common: dict, *, declared=None) -> tuple[Path, dict]:
    """The notebook of a stage and its parameters: the keys of ``common`` that its parameters cell
    declares, then its own params file. ``declared``: the declared names when already known."""
    nb = notebook_of(stage)
    own = load_params(stage["params"]) if stage.get("params") else {}
    declared = notebook_parameters(nb) if declared is None else declared
    merged = {k: v for k, v in common.items() if k in declared}
    merged.update(own)
    return nb, merged


def stage_wave(stage: dict, common: dict) -> tuple[int, bool]:
    """The stage's wave, and whether ``wave_if_missing`` moved it: ``wave_if_missing: {param,
    wave}`` moves a stage to a later wave when the path named by that parameter does not exist
    (e.g. the answer-interface audit of the reference release runs beside the release notebook, but
    after it when it must audit our own release)."""
    wave = int(stage.get("wave", 0))
    alt = stage.get("wave_if_missing")
    if alt:
        own = load_params(stage["params"]) if stage.get("params") else {}
        value = own.get(alt["param"], common.get(alt["param"]))
        if not value or not paths.resolve(value).exists():
            return int(alt["wave"]), True
    return wave, False


def match_only(stages: list[dict], only: list[str]) -> list[str]:
    """Notebook names of the stages named by ``only`` (full name, or the name without its number:
    ``dimensional`` for ``03_dimensional``). Unknown names raise :class:`InputError`."""
    if not only:
        raise InputError("--only needs at least one stage name; stages: " + _stage_list(stages))
    by_alias = {}
    for s in stages:
        nb = s["notebook"]
        by_alias[nb] = nb
        by_alias.setdefault(nb.split("_", 1)[-1], nb)
    unknown = [n for n in only if n not in by_alias]
    if unknown:
        raise InputError(f"unknown stage(s) {unknown}; stages: " + _stage_list(stages))
    return list(dict.fromkeys(by_alias[n] for n in only))


def _stage_list(stages: list[dict]) -> str:
    return ", ".join(f"{s['notebook']} ({s['notebook'].split('_', 1)[-1]})" for s in stages)


def plan(stages: list[dict], common: dict) -> tuple[dict[str, int], dict[str, list[str]]]:
    """Wave and needs of every stage. ``needs`` defaults to every (not on-demand) stage of an earlier
    wave; a stage moved by ``wave_if_missing`` needs every earlier stage too."""
    waves, moved = {}, {}
    for s in stages:
        waves[s["notebook"]], moved[s["notebook"]] = stage_wave(s, common)
    names = {s["notebook"] for s in stages}
    needs = {}
    for s in stages:
        n = s["notebook"]
        explicit = s.get("needs")
        if explicit is not None and not moved[n]:
            unknown = [x for x in explicit if x not in names]
            if unknown:
                raise InputError(f"stage {n}: needs unknown stage(s) {unknown}", field="stages")
            needs[n] = list(explicit)
        else:
            needs[n] = [t["notebook"] for t in stages if not t.get("on_demand") and waves[t["notebook"]] < waves[n]]
    return waves, needs


def closure(name: str, needs: dict[str, list[str]]) -> list[str]:
    """Every stage ``name`` needs, directly or through another stage (in first-seen order)."""
    seen: list[str] = []
    todo = list(needs.get(name, []))
    while todo:
        n = todo.pop(0)
        if n not in seen:
            seen.append(n)
            todo += needs.get(n, [])
    return seen


def downstream(names: list[str], needs: dict[str, list[str]], stages: list[dict]) -> list[str]:
    """Stages (not on-demand) that need any of ``names``, directly or through another stage."""
    found = set(names)
    grew = True
    while grew:
        grew = False
        for s in stages:
            n = s["notebook"]
            if n not in found and not s.get("on_demand") and set(needs[n]) & found:
                found.add(n)
                grew = True
    return [s["notebook"] for s in stages if s["notebook"] in found and s["notebook"] not in names]
