"""The ``resti`` command line: verify, attack, reoption, measure, synth, run."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ..errors import BusyError, ContractError, InputError, OutputError, RestiError

# Exit codes: 0 success; 1 the work ran and found a failure (verify FAILED, a notebook or an invariant
# failed); 2 bad input or a refused output folder (one line on stderr); 3 the output folder is busy.
EXIT_FAILED, EXIT_INPUT, EXIT_BUSY = 1, 2, 3
MAX_SKIPPED_SHOWN = 10


def cli_path(text: str) -> str:
    """A path given on the command line: ``${SHARED}`` expanded, ``~`` expanded, and a relative path
    taken from the current directory (params *files* state their paths from the repository root)."""
    from .. import paths

    p = Path(str(text).replace("${SHARED}", str(paths.shared_dir()))).expanduser()
    return str(p if p.is_absolute() else Path.cwd() / p)


def _cmd_verify(a) -> int:
    from ..release.verify import format_text, to_json, verify_path

    v = verify_path(a.path, legacy=a.legacy)
    print(to_json(v) if a.json else format_text(v))
    return 0 if v["passed"] else EXIT_FAILED


def _cmd_attack(a) -> int:
    from ..release.audit import attack_release, format_headline

    try:
        run = attack_release(a.path, families=a.families or "all", attacks=a.attacks, fast=a.fast, alpha=a.alpha,
                             progress=True, rows=a.rows)
    except ValueError as e:
        print(f"resti attack: {e}", file=sys.stderr)
        return EXIT_INPUT
    rel, skipped, table = run.release, run.skipped, run.table
    if rel.meta_error is not None:
        print(f"resti attack: input error: file {rel.meta_file}: {rel.meta_error} (the rows are attacked; "
              "run resti verify)", file=sys.stderr)
    if skipped:
        shown = "; ".join(f"{rid}: {why}" for rid, why in list(skipped.items())[:MAX_SKIPPED_SHOWN])
        more = f" (and {len(skipped) - MAX_SKIPPED_SHOWN} more)" if len(skipped) > MAX_SKIPPED_SHOWN else ""
        print(f"resti attack: {len(skipped)} of {len(rel.accepted)} rows of {rel.accepted_file} skipped as "
              f"structurally bad: {shown}{more}", file=sys.stderr)
    if len(skipped) >= len(rel.accepted):  # nothing left to attack
        print(f"resti attack: no row of {rel.accepted_file} can be attacked", file=sys.stderr)
        return EXIT_INPUT
    head = run.headline
    shown = head if a.headline else table
    if a.format == "json":
        print(json.dumps(shown.to_dict("records"), indent=1, default=float))
    elif a.format == "csv":
        sys.stdout.write(shown.to_csv(index=False, lineterminator="\n"))
    else:
        print(format_headline(head, alpha=a.alpha, counts=run.counts))
        if not a.headline:
            t = table.copy()
            for c in ("coverage", "accuracy", "chance", "min_detectable"):
                t[c] = t[c].map(lambda x: f"{x:.3f}")
            t["hits"] = t["hits"].map(lambda x: f"{x:g}")
            for c in ("p_value", "p_holm"):
                t[c] = t[c].map(lambda x: f"{x:.3g}")
            print()
            print(t.to_markdown(index=False))
    if skipped or rel.meta_error is not None:
        return EXIT_INPUT
    if a.fail_on_significant and bool(table["significant"].any()):
        print(f"resti attack: {int(table['significant'].sum())} Holm-significant attack rows "
              "(--fail-on-significant)", file=sys.stderr)
        return EXIT_FAILED
    return 0


def _cmd_reoption(a) -> int:
    from ..release.reoption import filter_summary, reoption_release
    from .notebooks import load_params

    params = load_params(a.params) if a.params else {}
    if a.params:
        from ..defaults import check_params, load

        check_params(params, load("reoption"), file=a.params, what="reoption params")
    seed = a.seed if a.seed is not None else params.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise InputError(f"seed {seed!r} is not an integer", file=a.params, field="seed")
    opts = params.get("options")
    if opts is not None and not isinstance(opts, dict):
        raise InputError(f"options must be a mapping, got {type(opts).__name__}", file=a.params, field="options")
    res = reoption_release(a.release, a.out, seed=seed, options=opts)
    counts = res.meta["counts"]
    new = len(res.dropped)
    print(f"wrote {res.out_dir}: {counts['accepted']} rows rebuilt, {counts['excluded'] - new} exclusions copied"
          + (f", {new} rows excluded (no_valid_options: no options meet the constraints)" if new else "")
          + f", seed {seed}, {res.seconds:.1f} s; verify: {'PASSED' if res.validation['passed'] else 'FAILED'}")
    print("answer letters: " + " ".join(f"{k}={n}" for k, n in res.meta["answer_letters"].items()))
    print(filter_summary(res.meta["reoption"].get("adversarial_filter") or []))
    return 0


def _cmd_measure(a) -> int:
    from ..measure import measure_main

    return measure_main(a.rest)


def _cmd_synth(a) -> int:
    from ..synth import check_scale, generate

    check_scale(a.scale)
    summary = generate(Path(a.out), seed=a.seed, scale=a.scale)
    print(json.dumps(summary, indent=1, default=str))
    return 0


def _cmd_run(a) -> int:
    from .pipeline import run

    return run(a.params, only=a.only, jobs=a.jobs, force=a.force, baseline=a.baseline)


def _stage_help() -> str:
    """The stages of params/default.yaml, for ``resti run --help``."""
    try:
        from .plan import main_config

        stages = main_config().get("stages") or []
        names = [f"{s['notebook']} ({s['notebook'].split('_', 1)[-1]}{', on demand' if s.get('on_demand') else ''})"
                 for s in stages]
    except (InputError, OSError, KeyError, TypeError, AttributeError):
        return ""
    return "stages of params/default.yaml (full name or the part after the number): " + ", ".join(names)


def _attack_help() -> str:
    """The registered families and attacks, for ``resti attack --help`` (imports the attack registry)."""
    from ..options.attacks import ATTACKS
    from ..options.attacks.registry import FAMILIES, KEYED_FAMILIES

    blind = [f for f in FAMILIES if f not in KEYED_FAMILIES]
    return (f"families: {', '.join(blind)} (the blind suite); {', '.join(KEYED_FAMILIES)} (answer-key readers, "
            f"named explicitly). attacks: " + ", ".join(sorted(ATTACKS)))


def build_parser(*, full_help: bool = False) -> argparse.ArgumentParser:
    """The command line. ``full_help``: list the registered attacks and the stages in the help
    (costs an import of the attack registry, so only when help is asked for)."""
    p = argparse.ArgumentParser(prog="resti", description=__doc__,
                                epilog="`resti COMMAND --help` describes each command. Paths given on the "
                                       "command line are taken from the current directory.")
    sub = p.add_subparsers(dest="cmd", required=True)

    v = sub.add_parser("verify", help="validate a ReSTI-schema release (folder or file)",
                       description="Structural validation of a ReSTI-schema release (folder or accepted-rows file).")
    v.add_argument("path", type=cli_path)
    v.add_argument("--json", action="store_true", help="print the validation object as JSON")
    v.add_argument("--legacy", type=cli_path,
                   help="legacy qa.parquet: also check that every legacy row is accounted for")
    v.set_defaults(fn=_cmd_verify)

    at = sub.add_parser("attack", help="blind attacks on a release (options, format, question, other rows, "
                        "metadata, learned)",
                        description="Blind attacks on a release: everything but the video (the options, the question, "
                                    "other rows of the video, metadata), accuracy against chance 1/5, Holm over the "
                                    "table.", epilog=_attack_help() if full_help else None)
    at.add_argument("path", type=cli_path)
    at.add_argument("--format", choices=["md", "csv", "json"], default="md",
                    help="format on stdout (md: the headline, then the table)")
    at.add_argument("--alpha", type=float, default=0.05, help="Holm family-wise error rate over every table row")
    at.add_argument("--families", nargs="*", default=None,
                    help="attack families (default: every blind family; listed below)")
    at.add_argument("--fast", action="store_true", help="leave the learned families out")
    at.add_argument("--attacks", nargs="*", default="all", help="attack names (default: all of the families; "
                    "listed below)")
    at.add_argument("--rows", choices=["all", "subset", "residual"], default="all",
                    help="rows scored: all; subset: the evaluation subset's rows, read on their own; residual: the rows "
                    "no named structural leak touches, read with the whole file (both need evaluation_subset.json)")
    at.add_argument("--headline", action="store_true",
                    help="print only the headline: one row per task/source cell, significant cells first")
    at.add_argument("--fail-on-significant", action="store_true",
                    help="exit with status 1 when any attack is Holm-significant (for CI)")
    at.set_defaults(fn=_cmd_attack)

    ro = sub.add_parser("reoption", help="rebuild the answer options of a release (same rows and details, "
                        "new distractors and letters)")
    ro.add_argument("--release", default="${SHARED}/data/resti_v5", type=cli_path, help="input release folder or file")
    ro.add_argument("--out", required=True, type=cli_path, help="output folder: new, empty or an earlier resti "
                    "release (replaced atomically; never the input)")
    ro.add_argument("--seed", type=int, default=None, help="option seed (default: params seed, else 0)")
    ro.add_argument("--params", default=None, type=cli_path,
                    help="params YAML with seed and options (e.g. params/reoption.yaml)")
    ro.set_defaults(fn=_cmd_reoption)

    m = sub.add_parser("measure", help="evaluate measurement contracts against the sources "
                       "(`resti measure --help`)", add_help=False)
    m.add_argument("rest", nargs=argparse.REMAINDER)
    m.set_defaults(fn=_cmd_measure)

    s = sub.add_parser("synth", help="generate the mini-world (sources + legacy benchmark + manifest)",
                       description="Generate the mini-world: sources in their real formats, a legacy benchmark "
                                   "with injected defects, and the manifest of those defects.")
    s.add_argument("out", type=cli_path)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--scale", type=int, default=None,
                   help="copies of the 2,064-row legacy structure (1 to 1000; default: the small world)")
    s.set_defaults(fn=_cmd_synth)

    r = sub.add_parser("run", help="the main job: notebooks -> release, tables, figures, report",
                       description="The main job. Stages whose notebook, code, params, inputs and upstream "
                                   "stages are unchanged since their last run are skipped.",
                       epilog=_stage_help() if full_help else None)
    r.add_argument("--params", default=None, type=cli_path,
                   help="main params file (default: params/default.yaml of the repository)")
    r.add_argument("--only", nargs="+", default=None, metavar="STAGE",
                   help="run these stages (even when up to date), then every stage downstream of them that "
                        "became stale; names are listed below")
    r.add_argument("--force", action="store_true", help="rerun every stage, up to date or not")
    r.add_argument("--jobs", type=int, default=None, help="parallel notebooks (default: cores)")
    r.add_argument("--baseline", action="store_true",
                   help="make this run the baseline the report's What changed section compares later runs with "
                        "(default: the first run of the output folder)")
    r.set_defaults(fn=_cmd_run)
    return p


def _measure_argv(rest: list[str]) -> list[str]:
    """``resti measure`` arguments with the contract file and ``--params`` taken from the current
    directory (the command parses them itself; ``-`` is stdin)."""
    out, params_next = [], False
    for a in rest:
        if params_next:
            out.append(cli_path(a))
            params_next = False
        elif a == "--params":
            out.append(a)
            params_next = True
        elif a.startswith("--params="):
            out.append("--params=" + cli_path(a.split("=", 1)[1]))
        elif a.startswith("-"):
            out.append(a)
        else:
            out.append(cli_path(a))
    return out


def _closed_pipe() -> int:
    """stdout was closed by the reader (``resti attack ... | head``): stop quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except OSError:
        pass
    return 141  # 128 + SIGPIPE, as a command killed by the closed pipe


def exit_code(e: BaseException) -> int:
    if isinstance(e, BusyError):
        return EXIT_BUSY
    if isinstance(e, (InputError, OutputError, ContractError, OSError)):
        return EXIT_INPUT
    return EXIT_FAILED


def main(argv: list[str] | None = None) -> int:
    """Run one command; every resti error ends as one line on stderr and a non-zero exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    cmd = "resti"
    try:
        if argv[:1] == ["measure"]:  # its own parser (and its own --help)
            cmd = "resti measure"
            from ..measure import measure_main

            rc = measure_main(_measure_argv(argv[1:]))
        else:
            args = build_parser(full_help=bool({"-h", "--help"} & set(argv))).parse_args(argv)
            cmd = f"resti {args.cmd}"
            rc = args.fn(args)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return rc
    except BrokenPipeError:
        return _closed_pipe()
    except RestiError as e:
        kind = {InputError: "input error", OutputError: "output refused", BusyError: "busy"}.get(type(e), "error")
        print(f"{cmd}: {kind}: {e}", file=sys.stderr)
        return exit_code(e)
    except OSError as e:  # the file system refused a read or a write (permissions, disk full, ...)
        where = f" {e.filename}" if getattr(e, "filename", None) else ""
        print(f"{cmd}: system error:{where}: {e.strerror or e}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print(f"{cmd}: interrupted; the previous outputs are intact", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
