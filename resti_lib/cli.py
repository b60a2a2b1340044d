"""The ``resti`` command line: verify, attack, reoption, measure, synth, run."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import InputError


def _cmd_verify(a) -> int:
    from .verify import format_text, to_json, verify_path

    v = verify_path(a.path, legacy=a.legacy)
    print(to_json(v) if a.json else format_text(v))
    return 0 if v["passed"] else 1


def _cmd_attack(a) -> int:
    from .answer_interface import format_headline
    from .io.benchmark import load_release
    from .options.attacks import attack_table, headline, select

    try:
        names = select(a.families or None, None if a.attacks in (None, "all", ["all"]) else a.attacks, fast=a.fast)
    except ValueError as e:
        print(f"resti attack: {e}", file=sys.stderr)
        return 2
    rel = load_release(a.path, strict=False)
    table = attack_table(rel.accepted.to_dict("records"), families="all", attacks=names, alpha=a.alpha,
                         progress=True)
    head = format_headline(headline(table), alpha=a.alpha, tests=len(table))
    if a.format == "json":
        print(head, file=sys.stderr)
        print(json.dumps(table.to_dict("records"), indent=1, default=float))
    elif a.format == "csv":
        print(head, file=sys.stderr)
        sys.stdout.write(table.to_csv(index=False, lineterminator="\n"))
    else:
        shown = table.copy()
        for c in ("coverage", "accuracy", "chance", "min_detectable"):
            shown[c] = shown[c].map(lambda x: f"{x:.3f}")
        shown["hits"] = shown["hits"].map(lambda x: f"{x:g}")
        for c in ("p_value", "p_holm"):
            shown[c] = shown[c].map(lambda x: f"{x:.3g}")
        print(head + "\n")
        print(shown.to_markdown(index=False))
    if a.fail_on_significant and bool(table["significant"].any()):
        print(f"resti attack: {int(table['significant'].sum())} Holm-significant attack rows "
              "(--fail-on-significant)", file=sys.stderr)
        return 1
    return 0


def _cmd_reoption(a) -> int:
    from .reoption import ReoptionError, reoption_release
    from .runner import load_params

    params = load_params(a.params) if a.params else {}
    seed = a.seed if a.seed is not None else int(params.get("seed", 0))
    try:
        res = reoption_release(a.release, a.out, seed=seed, options=params.get("options"))
    except ReoptionError as e:
        print(f"resti reoption: {e}", file=sys.stderr)
        return 1
    counts = res.meta["counts"]
    print(f"wrote {res.out_dir}: {counts['accepted']} rows rebuilt, {counts['excluded']} exclusions copied, "
          f"seed {seed}, {res.seconds:.1f} s; verify: {'PASSED' if res.validation['passed'] else 'FAILED'}")
    print("answer letters: " + " ".join(f"{k}={n}" for k, n in res.meta["answer_letters"].items()))
    return 0


def _cmd_measure(a) -> int:
    from .measure import measure_main

    return measure_main(a.rest)


def _cmd_synth(a) -> int:
    from .synth import generate

    summary = generate(Path(a.out), seed=a.seed, scale=a.scale)
    print(json.dumps(summary, indent=1, default=str))
    return 0


def _cmd_run(a) -> int:
    from .pipeline import run

    return run(a.params, only=a.only, jobs=a.jobs)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="resti", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)

    v = sub.add_parser("verify", help="validate a ReSTI-schema release (folder or file)")
    v.add_argument("path")
    v.add_argument("--json", action="store_true", help="print the validation object as JSON")
    v.add_argument("--legacy", help="legacy qa.parquet: also check that every legacy row is accounted for")
    v.set_defaults(fn=_cmd_verify)

    at = sub.add_parser("attack", help="blind attacks on a release (options, format, question, other rows, "
                        "metadata, learned)")
    at.add_argument("path")
    at.add_argument("--format", choices=["md", "csv", "json"], default="md",
                    help="table format on stdout (md: headline first; csv/json: headline on stderr)")
    at.add_argument("--alpha", type=float, default=0.05, help="Holm family-wise error rate over every table row")
    at.add_argument("--families", nargs="*", default=None,
                    help="attack families (default: all): option format typicality question cross_row "
                    "metadata learned_option learned_question")
    at.add_argument("--fast", action="store_true", help="leave the learned families out")
    at.add_argument("--attacks", nargs="*", default="all", help="attack names (default: all of the families)")
    at.add_argument("--fail-on-significant", action="store_true",
                    help="exit with status 1 when any attack is Holm-significant (for CI)")
    at.set_defaults(fn=_cmd_attack)

    ro = sub.add_parser("reoption", help="rebuild the answer options of a release (same rows and details, "
                        "new distractors and letters)")
    ro.add_argument("--release", default="${SHARED}/data/resti_v5", help="input release folder or file")
    ro.add_argument("--out", required=True, help="output folder (replaced atomically)")
    ro.add_argument("--seed", type=int, default=None, help="option seed (default: params seed, else 0)")
    ro.add_argument("--params", default=None, help="params YAML with seed and options (e.g. params/reoption.yaml)")
    ro.set_defaults(fn=_cmd_reoption)

    m = sub.add_parser("measure", help="evaluate measurement contracts against the sources",
                       add_help=False)
    m.add_argument("rest", nargs=argparse.REMAINDER)
    m.set_defaults(fn=_cmd_measure)

    s = sub.add_parser("synth", help="generate the mini-world (sources + legacy benchmark + manifest)")
    s.add_argument("out")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--scale", type=int, default=None)
    s.set_defaults(fn=_cmd_synth)

    r = sub.add_parser("run", help="the main job: notebooks -> release, tables, figures, report")
    r.add_argument("--params", default="params/default.yaml")
    r.add_argument("--only", nargs="*", default=None, help="run only these notebooks/stages")
    r.add_argument("--jobs", type=int, default=None, help="parallel notebooks (default: cores)")
    r.set_defaults(fn=_cmd_run)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.fn(args)
    except InputError as e:
        print(f"resti {args.cmd}: input error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
