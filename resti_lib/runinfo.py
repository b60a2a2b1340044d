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

from . import __version__, paths

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


def stage_own_params(cfg: dict) -> dict[str, dict]:
    """Each stage's own params file, by notebook name (a missing file is reported by the caller)."""
    from .runner import load_params

    out = {}
    for s in cfg.get("stages") or []:
        out[s["notebook"]] = load_params(s["params"]) if s.get("params") else {}
    return out


def params_digest(cfg: dict, own: dict[str, dict]) -> str:
    """sha256 of the main params and every stage's params (output locations and ``jobs`` left out)."""
    common = {k: v for k, v in cfg.items() if k not in NOT_PARAMS}
    stages = {name: {k: v for k, v in p.items() if k not in NOT_PARAMS} for name, p in own.items()}
    return digest({"common": common, "stages": stages})


def run_context(cfg: dict, own: dict[str, dict] | None = None) -> dict:
    """The header block of the report and of ``release.json`` for the main params ``cfg``."""
    own = stage_own_params(cfg) if own is None else own
    ctx = {"input": input_description(cfg)}
    refs = sorted({str(p["reference_release"]) for p in own.values() if p.get("reference_release")})
    if refs:
        ctx["reference_release"] = refs[0]
    ctx["params_digest"] = params_digest(cfg, own)
    ctx["code"] = code_version()
    ctx["packages"] = package_versions()
    date = run_date()
    if date:
        ctx["date"] = date
    return ctx


def default_context() -> dict:
    """The run context of ``params/default.yaml`` (for a notebook run on its own)."""
    from .runner import load_params

    return run_context(load_params(Path(paths.PARAMS) / "default.yaml"))
