"""What a run was made from: input, params digest, code version, package versions and date.

The same block heads the HTML report and is written under ``run`` in ``release.json``
(:func:`run_context`). Two runs of the same code with the same params on the same input give the
same block, so reruns stay byte-identical: the date is taken from ``SOURCE_DATE_EPOCH`` when it is
set and left out otherwise (never the clock).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
from datetime import UTC, datetime
from pathlib import Path

from .. import __version__, paths

# Versions stated in the header: the libraries whose behaviour can change a number of the audit.
PACKAGES = ("numpy", "scipy", "pandas", "pyarrow", "matplotlib", "scikit-learn", "trimesh", "papermill",
            "nbconvert")
# Keys that say where outputs go, not what they contain: left out of digests, so the same run
# written to another folder has the same params digest.
OUTPUT_KEYS = frozenset({"output_dir", "release_dir", "tables_dir", "table_dir", "figure_dir", "audit_dir"})
NOT_PARAMS = OUTPUT_KEYS | {"jobs", "stages", "run_context"}
INPUT_KEYS = ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root", "video_map")


def canonical_json(obj) -> str:
    """Sorted keys, no spaces: the text that digests are taken of."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, default=str)


def digest(obj) -> str:
    return hashlib.sha256(canonical_json(obj).encode("utf-8")).hexdigest()


def _git(*args: str) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=paths.ROOT, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 and r.stdout.strip() else None


def code_version() -> dict:
    """``git describe`` and the commit when the code is a git checkout (``-dirty`` when it has
    uncommitted changes), else the package version only."""
    out = {"package": f"resti {__version__}"}
    if (paths.ROOT / ".git").exists():
        described = _git("describe", "--always", "--dirty", "--tags")
        commit = _git("rev-parse", "HEAD")
        if described:
            out["git"] = described
        if commit:
            out["commit"] = commit
    return out


def package_versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "absent"
    return out


def run_date() -> str | None:
    """The date of ``SOURCE_DATE_EPOCH`` (UTC, ISO 8601) when it is set to an integer, else None."""
    raw = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not raw:
        return None
    try:
        return datetime.fromtimestamp(int(raw), tz=UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    except (ValueError, OverflowError, OSError):
        return None


def _inside(child: str, parent: str) -> bool:
    try:
        paths.resolve(child).resolve().relative_to(paths.resolve(parent).resolve())
        return True
    except ValueError:
        return False


def input_description(cfg: dict) -> dict:
    """The mini-world (synthetic, with its seed) when the legacy benchmark lies in ``world_dir``;
    otherwise real data, with the paths as the params state them."""
    world, legacy = cfg.get("world_dir"), cfg.get("legacy_benchmark")
    if world and legacy and _inside(str(legacy), str(world)):
        return {"kind": "mini-world", "synthetic": True, "seed": int(cfg.get("world_seed", 0) or 0),
                "world_dir": str(world)}
    return {"kind": "real data", "synthetic": False,
            **{k: str(cfg[k]) for k in INPUT_KEYS if cfg.get(k)}}


def stage_params_digest(params: dict) -> str:
    """Digest of one stage's merged parameters, output locations left out (the ``params`` part of
    its stage key, :func:`resti_lib.run.stages.stage_key`)."""
    return digest({k: v for k, v in params.items() if k not in OUTPUT_KEYS and k != "run_context"})


def params_digest(cfg: dict, stage_digests: dict[str, str]) -> str:
    """sha256 of the main params (output locations and ``jobs`` left out) and the parameter digests
    of the stages a release is made from (:func:`stage_params_digest`)."""
    common = {k: v for k, v in cfg.items() if k not in NOT_PARAMS}
    return digest({"common": common, "stages": dict(sorted(stage_digests.items()))})


def run_context(cfg: dict, stage_digests: dict[str, str], *, reference: str | None = None) -> dict:
    """The header block of the report and of ``release.json``: the input, the params digest of the
    stages the release is made from (as they ran), the code and package versions, the date."""
    ctx = {"input": input_description(cfg)}
    if reference:
        ctx["reference_release"] = str(reference)
    ctx["params_digest"] = params_digest(cfg, stage_digests)
    ctx["code"] = code_version()
    ctx["packages"] = package_versions()
    date = run_date()
    if date:
        ctx["date"] = date
    return ctx


def default_context(params_file: str | Path | None = None, notebook: str = "99_release_report") -> dict:
    """The run context of a main params file (default ``params/default.yaml``) for ``notebook`` and
    the stages it needs, from their current params (for a notebook run on its own; ``resti run``
    passes the block itself)."""
    from .plan import closure, main_config, plan, stage_params

    cfg = main_config(params_file or Path(paths.PARAMS) / "default.yaml")
    stages = cfg.get("stages") or []
    common = {k: v for k, v in cfg.items() if k != "stages"}
    _, needs = plan(stages, common)
    by = {s["notebook"]: s for s in stages}
    names = [*closure(notebook, needs), notebook] if notebook in by else []
    digests = {n: stage_params_digest(stage_params(by[n], common)[1]) for n in names}
    ref = stage_params(by[notebook], common)[1].get("reference_release") if notebook in by else None
    return run_context(cfg, digests, reference=ref)
