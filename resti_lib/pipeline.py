"""The main job (``make report`` / ``resti run``): notebooks in order, then the report index.

``params/default.yaml`` lists the stages; each stage is a notebook with its own params file.
Keys of ``default.yaml`` that a notebook's ``parameters`` cell declares are passed to it too, so
source roots and the legacy path are stated once.
"""

from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tqdm.auto import tqdm

from . import paths
from .errors import InputError
from .runner import NotebookError, load_params, notebook_parameters, run_notebook


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
        if st.get("params") is not None:
            if not isinstance(st["params"], str):
                raise InputError(f"params {st['params']!r} is not a path", file=where, row=f"stage {i}",
                                 field="params")
            load_params(st["params"])


def stage_params(stage: dict, common: dict) -> tuple[Path, dict]:
    nb = paths.NOTEBOOKS / f"{stage['notebook']}.ipynb"
    if not nb.exists():
        raise InputError("stage notebook not found", file=nb, field="notebook")
    own = load_params(stage["params"]) if stage.get("params") else {}
    declared = notebook_parameters(nb)
    merged = {k: v for k, v in common.items() if k in declared}
    merged.update(own)
    return nb, merged


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
    from .io.files import atomic_write_bytes
    from .lock import folder_lock

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
        from .synth import generate

        t0 = time.perf_counter()
        print(f"resti run: generating the mini-world in {world} ...", file=sys.stderr)
        generate(world, seed=seed)
        atomic_write_bytes(stamp_file, stamp.encode("ascii"))
        print(f"resti run: mini-world ready ({time.perf_counter() - t0:.1f}s)", file=sys.stderr)
    return world


def missing_inputs(cfg: dict) -> list[str]:
    """Every input path of the params that does not exist (one message for all of them)."""
    from .sources.context import check_real_params

    return check_real_params(cfg)


def stage_wave(stage: dict, common: dict) -> int:
    """The stage's wave; ``wave_if_missing: {param, wave}`` moves it to a later wave when the path
    named by that parameter does not exist yet (e.g. the answer-interface audit of the reference
    release runs beside the release notebook, but after it when it must audit our own release)."""
    wave = int(stage.get("wave", 0))
    alt = stage.get("wave_if_missing")
    if alt:
        own = load_params(stage["params"]) if stage.get("params") else {}
        value = own.get(alt["param"], common.get(alt["param"]))
        if not value or not paths.resolve(value).exists():
            wave = int(alt["wave"])
    return wave


def run(params_file: str | Path = "params/default.yaml", *, only=None, jobs: int | None = None) -> int:
    """Run the stages of ``params_file``; returns a process exit code.

    The whole run holds the lock of its output folder (:func:`resti_lib.lock.run_lock`): a second
    run on the same output folder stops at once with a :class:`~resti_lib.errors.BusyError`.
    """
    from .lock import run_lock

    cfg = load_params(params_file)
    check_stages(cfg, params_file)
    with run_lock(paths.resolve(cfg.get("output_dir") or "outputs")):
        return _run(cfg, only=only, jobs=jobs)


def _run(cfg: dict, *, only=None, jobs: int | None = None) -> int:
    stages = cfg.get("stages") or []
    common = {k: v for k, v in cfg.items() if k != "stages"}
    ensure_world(cfg)
    problems = missing_inputs(cfg) if "legacy_benchmark" in cfg else []
    if problems:
        print("resti run: the params name inputs that are missing or wrong:\n  - " + "\n  - ".join(problems),
              file=sys.stderr)
        return 2
    if only:
        stages = [s for s in stages if s["notebook"] in only or s["notebook"].split("_", 1)[-1] in only]
        if not stages:
            print(f"resti run: no stage matches {only}", file=sys.stderr)
            return 2
    else:  # on-demand stages (e.g. the re-optioned public release) run only when named
        stages = [s for s in stages if not s.get("on_demand")]
    jobs = jobs or cfg.get("jobs") or os.cpu_count() or 1
    t0 = time.perf_counter()
    # stages are grouped into waves: stages of one wave are independent and run in parallel
    waves: dict[int, list[dict]] = {}
    for s in stages:
        waves.setdefault(stage_wave(s, common), []).append(s)
    out_root = paths.resolve(cfg.get("output_dir") or "outputs")
    nb_dir, html_dir = out_root / "notebooks", out_root / "report" / "notebooks"
    bar = tqdm(total=len(stages), desc="notebooks", unit="nb", file=sys.stderr)
    runs = []
    try:
        for w in sorted(waves):
            prepared = [stage_params(s, common) for s in waves[w]]
            with ThreadPoolExecutor(max_workers=max(1, min(jobs, len(prepared)))) as ex:
                futures = [ex.submit(run_notebook, nb, p, out_dir=nb_dir, html_dir=html_dir) for nb, p in prepared]
                for f in futures:
                    r = f.result()
                    runs.append(r)
                    bar.update(1)
                    bar.set_postfix_str(f"{r.name} {r.seconds:.1f}s")
    except NotebookError as e:
        bar.close()
        print(f"resti run: {e}", file=sys.stderr)
        return 1
    bar.close()
    from .report import write_index

    index = write_index(out_root)
    print(f"resti run: {len(runs)} notebooks in {time.perf_counter() - t0:.1f}s; report: {index}")
    return 0
