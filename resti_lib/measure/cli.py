"""``resti measure CONTRACT.json --params PARAMS.yaml [--json]``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import paths
from ..errors import InputError, SourceError
from ..io.params import read_params


def _load_params(path: str | None) -> dict:
    """The params of ``resti measure``: the shared keys, the operator settings, and any task's params
    (``resti measure --params params/<task>.yaml``), checked against their defaults."""
    if not path:
        return {}
    from ..defaults import check_params, load

    data = read_params(Path(path))
    schema: dict = {**{k: v for k, v in load("default").items() if k != "stages"}, **load("measure")}
    for f in sorted(paths.PARAMS.glob("*.yaml")):
        if f.stem not in ("default", "measure", "options", "real.example") and not f.stem.startswith("."):
            schema = {**load(f.stem), **schema}
    check_params(data, schema, file=Path(path), what="measure params")
    return data


def _load_contracts(path: str) -> dict | list:
    try:
        text = sys.stdin.read() if path == "-" else Path(path).read_text()
    except OSError as e:
        raise InputError(f"cannot read contract: {e}", file=path) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"invalid JSON: {e.msg}", file=path, row=e.lineno) from None
    if not isinstance(data, (dict, list)):
        raise InputError("a contract file holds one object or a list of objects", file=path)
    return data


def _human(i: int | None, c: dict, r: dict) -> str:
    head = f"[{i}] " if i is not None else ""
    what = f"{c.get('operator')} {c.get('source')} {c.get('sequence')} {c.get('entity')} t={c.get('times')}" \
        if isinstance(c, dict) else str(c)
    if "error" in r:
        return f"{head}{what}: ERROR {r['error']}"
    v = r["value"]
    if isinstance(v, float):
        v = f"{v:.6g}"
    elif isinstance(v, list):
        v = json.dumps(v)
    short = r["evidence"].get("shortened_to")
    note = f" (interval shortened to {short:.6f} s)" if isinstance(short, float) else ""
    return f"{head}{what}: {v} {r['unit'] or ''}{note}".rstrip()


def measure_main(argv: list[str] | None = None) -> int:
    """``resti measure CONTRACT.json --params PARAMS.yaml [--json]``.

    Returns the exit code: 0 when every contract evaluated, 1 when any gave an error, 2 when the
    contract or params file cannot be read, or a source file fails its checks (damage, a gap in the
    window).
    """
    ap = argparse.ArgumentParser(prog="resti measure", description="Evaluate measurement contracts "
                                 "(formats/contract.md) against the source datasets.")
    ap.add_argument("contract", help="CONTRACT.json: one contract object or a list ('-' = stdin)")
    ap.add_argument("--params", help="PARAMS.yaml with scannet_root / waymo_root / omni6d_root ...")
    ap.add_argument("--json", action="store_true", help="print {value, unit, evidence} as JSON")
    a = ap.parse_args(argv)
    try:
        params = _load_params(a.params)
        contracts = _load_contracts(a.contract)
    except InputError as e:
        print(f"resti measure: {e}", file=sys.stderr)
        return 2
    from . import evaluate_contracts

    try:
        results = evaluate_contracts(contracts, params)
    except SourceError as e:  # a source file fails its checks, or its samples leave a gap in the window
        print(f"resti measure: {e}", file=sys.stderr)
        return 2
    listed = results if isinstance(results, list) else [results]
    if a.json:
        print(json.dumps(results, indent=1))
    else:
        cs = contracts if isinstance(contracts, list) else [contracts]
        for i, (c, r) in enumerate(zip(cs, listed)):
            print(_human(i if isinstance(contracts, list) else None, c, r))
    return 1 if any("error" in r for r in listed) else 0
