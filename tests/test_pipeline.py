"""The main job end to end on the mini-world (one run per session, ``main_run``): nothing lost, every
report link resolves, outputs follow the umask, the terminal shows progress and a summary only,
a warm rerun does nothing, and editing one task's params reruns that task and what is downstream,
giving the bytes of a full run."""

import json
import re
import stat

import pandas as pd
import pytest

from resti_lib import values as V
from resti_lib.tasks import names as _task_names
from tests.conftest import MAIN_RUN_UMASK, run_cli
from tests.test_report import assert_links_resolve

TASK_NAMES = _task_names()

pytestmark = [pytest.mark.notebook, pytest.mark.slow]

RELEASE_FILES = ("resti.jsonl", "resti.parquet", "excluded.jsonl", "provenance.parquet", "validation.json",
                 "release.json", "SHA256SUMS")


def _ran(stdout: str) -> set[str]:
    """Stage names of the summary line ``resti run: N stage(s) run, ... (a, b)``."""
    m = re.search(r"resti run: (\d+) stage\(s\) run, (\d+) up to date, [\d.]+ s(?: \(([^)]*)\))?", stdout)
    assert m, stdout
    names = {x.strip() for x in (m.group(3) or "").split(",") if x.strip()}
    assert len(names) == int(m.group(1))
    return names


def _rows(path):
    return {json.loads(x)["Legacy Row Key"]: json.loads(x) for x in path.read_text().splitlines()}


def test_main_job_end_to_end(main_run, miniworld):
    out, cfg = main_run.out, main_run.cfg
    rel = out / "release"
    n_legacy = sum(1 for _ in (miniworld / "manifest.jsonl").open())
    acc = (rel / "resti.jsonl").read_text().splitlines()
    exc = (rel / "excluded.jsonl").read_text().splitlines()
    assert len(acc) + len(exc) == n_legacy
    v = json.loads((rel / "validation.json").read_text())
    assert v["passed"] and v["checks"]["legacy_coverage"]["status"] == "pass"
    # the release.json check compared its counts (it is written beside validation.json)
    assert v["checks"]["release_json"]["status"] == "pass"
    rendered = {p.stem for p in (out / "report" / "notebooks").glob("*.html")}
    assert {s["notebook"] for s in cfg["stages"] if not s.get("on_demand")} <= rendered
    assert assert_links_resolve(out / "report" / "index.html") > 20
    # no Holm-significant option-only attack on the rebuilt options (the option rules and the learned
    # option-only attacker), except the label prior of categorical answers (a property of the answers,
    # not of the options); the table holds the whole suite of `resti attack`, whose other families
    # (the same video's rows) are issue 19's
    att = pd.read_csv(out / "tables" / "attacks_release.csv")
    sig = att[att["significant"] & (att["attack"] != "label_prior") & att["family"].isin(["option", "learned_option"])]
    assert sig.empty, sig.to_string()


def test_release_json_states_the_run(main_run, miniworld):
    meta = json.loads((main_run.out / "release" / "release.json").read_text())
    run = meta["run"]
    assert run["input"] == {"kind": "mini-world", "synthetic": True, "seed": 0, "world_dir": str(miniworld)}
    assert run["date"] == "2023-11-14T22:13:20Z"  # SOURCE_DATE_EPOCH=1700000000
    assert re.fullmatch(r"[0-9a-f]{64}", run["params_digest"])
    # the digest the pipeline states equals the one computed from the params files alone
    from resti_lib.run.runinfo import default_context

    assert default_context(main_run.params)["params_digest"] == run["params_digest"]
    assert run["code"]["package"].startswith("resti ")
    assert {"python", "numpy", "pandas"} <= set(run["packages"])
    index = (main_run.out / "report" / "index.html").read_text()
    assert run["params_digest"] in index and "2023-11-14T22:13:20Z" in index


def test_release_json_records_each_tasks_adversarial_filter(main_run):
    """Every task's option stage checked its options with the adversarial filter on the rows no
    structural leak touches; release.json records its checks per task. The rows checked are counted
    again here from the shipped rows of each task (a categorical task has nothing to check)."""
    from resti_lib.io.benchmark import load_release
    from resti_lib.options.structural import evaluation_subset, residual_ids
    from resti_lib.release.verify import release_interface

    rel = main_run.out / "release"
    meta = json.loads((rel / "release.json").read_text())
    iface, _ = release_interface(load_release(rel, strict=True, known_tasks=TASK_NAMES))
    rows = [json.loads(x) for x in (rel / "resti.jsonl").read_text().splitlines()]
    log = meta["adversarial_filter"]
    assert set(log) == {r["Task"] for r in rows}
    for task, rounds in log.items():
        own = [r for r in rows if r["Task"] == task]
        if task == "Spatial Relation":
            assert rounds == []
            continue
        residual = residual_ids(own, iface, evaluation_subset(own, iface, seed=main_run.cfg.get("seed", 0)))
        assert rounds and rounds[-1]["rows_checked"] == len(residual), task  # the last check read the shipped rows
        # every way a filter ends (nothing to redraw: the rows it names follow a set of another task's stage)
        assert rounds[-1]["stopped"] in ("at chance", "rounds", "draw leaks", "max_redrawn_share", "nothing to redraw")
    # the report shows the same record, a row per task
    index = (main_run.out / "report" / "index.html").read_text()
    table = index[index.index("Adversarial filter of the option stage"):]
    table = table[:table.index("</table>")]
    assert table.count("<tr>") == len(log)  # one body row per task (the header row has a style)
    assert table.count(">nothing to check<") == 1  # Spatial Relation


def test_outputs_follow_the_umask(main_run):
    want_file, want_dir = 0o666 & ~MAIN_RUN_UMASK, 0o777 & ~MAIN_RUN_UMASK  # 0664 and 0775
    wrong = []
    for p in [main_run.out, *main_run.out.rglob("*")]:
        mode = stat.S_IMODE(p.stat().st_mode)
        if mode != (want_dir if p.is_dir() else want_file):
            wrong.append(f"{p.relative_to(main_run.out)} {oct(mode)}")
    assert not wrong, wrong[:10]


def test_run_prints_progress_and_a_summary_only(main_run):
    err, out = main_run.stderr, main_run.stdout
    for noise in ("without encryption", "Traceback", "WARNING", "KeyboardInterrupt", "DeprecationWarning"):
        assert noise not in err, err[-2000:]
    assert "notebooks" in err  # the progress bar
    assert re.search(r"release: \d+ legacy rows \(synthetic mini-world, seed 0\) -> \d+ accepted \+ \d+ excluded; "
                     r"verify PASSED", out), out
    assert "blind attacks on our release:" in out and "report: " in out
    assert _ran(out) == {s["notebook"] for s in main_run.cfg["stages"] if not s.get("on_demand")}


def test_warm_rerun_does_nothing(main_run):
    rel = main_run.out / "release"
    before = {p.name: p.stat().st_mtime_ns for p in rel.iterdir()}
    r = run_cli(["run", "--params", str(main_run.params)])
    assert r.returncode == 0, r.stderr
    assert _ran(r.stdout) == set()
    assert {p.name: p.stat().st_mtime_ns for p in rel.iterdir()} == before


def test_one_task_params_edit_reruns_it_and_downstream_like_a_full_run(main_run, dimensional_edit):
    # a copy of the session's outputs; one task's params edited (``DIMENSIONAL_EDIT``: one more printed
    # decimal, a wider tolerance): that task and what is downstream rerun
    ed = dimensional_edit
    # 01: a box's candidate edges follow the dimensions asked of its subject (Task.follows)
    assert _ran(ed.edit_stdout) == {"03_dimensional", "01_grounding", "99_release_report"}

    # the release changed accordingly: Dimensional answers print more decimals, Grounding answers are
    # the same (their candidates may follow the new dimension candidates), every other task's rows are
    # the session run's rows; rows that left the release did so for want of valid options, by name
    old, new = _rows(main_run.out / "release" / "resti.jsonl"), _rows(ed.edited / "release" / "resti.jsonl")
    gone = old.keys() - new.keys()
    assert new.keys() <= old.keys()
    excluded = {json.loads(x)["key"]: json.loads(x)
                for x in (ed.edited / "release" / "excluded.jsonl").read_text().splitlines()}
    for k in gone:
        assert "no_valid_options" in excluded[k]["reason_codes"], k
        assert old[k]["Task"] in ("Dimensional Measurement", "3D Video Grounding"), k
    dims = [k for k, r in new.items() if r["Task"] == "Dimensional Measurement"]
    assert dims
    for k in dims:
        assert V.parse(new[k]["Answer Detail"]).decimals >= 3
        assert V.parse(old[k]["Answer Detail"]).decimals < V.parse(new[k]["Answer Detail"]).decimals
    for k, r in new.items():
        if r["Task"] == "3D Video Grounding":
            assert (r["Answer Detail"], r["Question"]) == (old[k]["Answer Detail"], old[k]["Question"]), k
        elif r["Task"] != "Dimensional Measurement":
            assert r == old[k], k
    assert (ed.edited / "report" / "index.html").read_bytes() != (main_run.out / "report" / "index.html").read_bytes()

    # the edit undone: the same three stages rerun and every release file, table and the index are the
    # bytes of the session's full run with these params
    inc = ed.inc
    assert _ran(ed.undo_stdout) == {"03_dimensional", "01_grounding", "99_release_report"}
    full = main_run.out
    for name in RELEASE_FILES:
        assert (inc / "release" / name).read_bytes() == (full / "release" / name).read_bytes(), name
    assert (inc / "report" / "index.html").read_bytes() == (full / "report" / "index.html").read_bytes()
    tabs = sorted(p.name for p in (full / "tables").iterdir())
    assert sorted(p.name for p in (inc / "tables").iterdir()) == tabs
    for name in tabs:
        assert (inc / "tables" / name).read_bytes() == (full / "tables" / name).read_bytes(), name
    assert not list((inc / "report").glob("what_changed*"))
    assert set(TASK_NAMES) >= {r["Task"] for r in new.values()}
