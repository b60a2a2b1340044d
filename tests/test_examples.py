"""Before/after examples: chosen per task and verdict from the provenance, legacy beside repaired."""

from __future__ import annotations

import json

import pandas as pd

from resti_lib.report.examples import VERDICTS, card_html, one_per_verdict, select_examples
from tests.helpers import row

DISP, DIM = "Displacement & Path Length", "Dimensional Measurement"


def _prov(rows):
    out = []
    for i, (task, verdict, defects) in enumerate(rows):
        out.append({"row": i, "key": f"k{i}", "task": task, "source": "ScanNet", "video": "scene0900_00.mp4",
                    "verdict": verdict, "reasons": json.dumps(["grouped_referent"] if verdict == "excluded" else []),
                    "defects": json.dumps(defects), "frames": json.dumps({"t0": 0.0, "t1": 2.0}),
                    "transform_chain": "P(t)", "source_files": json.dumps(["/x/scene0900_00.sens"]),
                    "evidence": json.dumps({"comparison": {"legacy_text": "2.00m", "residual_si": 0.5, "agrees": False,
                                                           "rule": "r"}, "options": {"long": "x" * 5000}}),
                    "legacy_detail": "2.00m", "new_detail": "2.50m" if verdict != "excluded" else None})
    return pd.DataFrame(out)


def test_examples_per_task_and_verdict_most_defects_first():
    spec = [(DISP, "retained", []), (DISP, "corrected", ["value_mismatch"]),
            (DISP, "corrected", ["value_mismatch", "unit_tag_missing"]), (DISP, "corrected", []),
            (DIM, "excluded", ["grouped_referent"]), (DIM, "re-contracted", [])]
    prov = _prov(spec)
    legacy = pd.DataFrame([row(task=t, rid=i, question=f"legacy question {i}") for i, (t, _, _) in enumerate(spec)])
    accepted = pd.DataFrame([{**row(task=t, rid=i, question=f"repaired question {i}"), "Legacy Row Key": f"k{i}"}
                             for i, (t, v, _) in enumerate(spec) if v != "excluded"])
    ex = select_examples(prov, legacy, accepted, per_verdict=2)
    # registry order: Dimensional before Displacement; verdicts in order; two corrected rows, most defects first
    assert list(zip(ex["task"], ex["verdict"], ex["row"])) == [
        (DIM, "re-contracted", 5), (DIM, "excluded", 4), (DISP, "retained", 0), (DISP, "corrected", 2),
        (DISP, "corrected", 1)]
    r = ex.set_index("row").loc[2]
    assert r["legacy_question"] == "legacy question 2" and r["question"] == "repaired question 2"
    assert r["comparison"] == "legacy 2.00m; recomputed 2.50m; residual +0.5 (SI); disagree; rule: r"
    assert "options" not in r["evidence"] and r["source_files"] == "scene0900_00.sens"
    assert ex.set_index("row").loc[4, "question"] == ""  # excluded: no repaired row
    card = card_html(ex[ex["row"] == 4].iloc[0].to_dict())
    assert "Excluded" in card and "grouped_referent" in card and "legacy question 4" in card
    first = one_per_verdict(ex)
    assert list(first["verdict"]) == [v for v in VERDICTS if v in set(ex["verdict"])]


def test_default_run_has_examples_of_every_task_and_verdict(main_run):
    from resti_lib.tasks import names

    ex = pd.read_csv(main_run.out / "tables" / "examples.csv", dtype=str, keep_default_na=False)
    prov = pd.read_parquet(main_run.out / "release" / "provenance.parquet")
    have = set(zip(prov["task"], prov["verdict"]))
    assert set(zip(ex["task"], ex["verdict"])) == have  # every (task, verdict) the run produced
    assert set(ex["task"]) == set(names())
    page = (main_run.out / "report" / "examples.html").read_text(encoding="utf-8")
    for task in names():
        assert f"<h3>{task.replace('&', '&amp;')}</h3>" in page
    index = (main_run.out / "report" / "index.html").read_text(encoding="utf-8")
    section = index.split('<section id="examples">', 1)[1].split("</section>", 1)[0]
    for v in VERDICTS:
        assert f'<span class="verdict {v}">{v}</span>' in section, v
