"""What changed: a run with other params against the baseline run of its output folder."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest

from resti_lib.report.changes import (
    BASELINE,
    SUMMARY,
    cells,
    large_effects,
    params_diff,
    rows_diff,
    update,
)
from tests.helpers import row, write_release

DIM = "Dimensional Measurement"


def test_params_diff_names_each_changed_value_once():
    old = {"stages": {"03_dimensional": {"rule": {"abs_tol": 0.002, "rel_tol": 0.002}, "seed": 0},
                      "05_displacement": {"rule": {"abs_tol": 0.002}, "seed": 0}},
           "library": {"params/options.yaml": {"separation": {"angle": {"min_sep_deg": 1.0}}}}}
    new = json.loads(json.dumps(old))
    new["stages"]["03_dimensional"]["rule"]["abs_tol"] = 0.3
    for s in new["stages"].values():
        s["seed"] = 1
    new["library"]["params/options.yaml"]["separation"]["angle"]["min_sep_deg"] = 2.0
    d = params_diff(old, new)
    assert d.to_dict("records") == [
        {"param": "rule.abs_tol", "before": "0.002", "after": "0.3", "read by": "03_dimensional"},
        {"param": "seed", "before": "0", "after": "1", "read by": "03_dimensional, 05_displacement"},
        {"param": "separation.angle.min_sep_deg", "before": "1.0", "after": "2.0", "read by": "params/options.yaml"}]
    assert params_diff(old, old).empty


def _folder(tmp_path, name, rows, excluded, verdicts, keys=None):
    rel = write_release(rows, excluded, tmp_path / name / "release")
    if keys is not None:  # the same legacy rows as another folder: their keys, whatever the repaired content
        recs = [dict(json.loads(x), **{"Legacy Row Key": k}) for x, k in
                zip((rel / "resti.jsonl").read_text().splitlines(), keys)]
        (rel / "resti.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    keys = [json.loads(x)["Legacy Row Key"] for x in (rel / "resti.jsonl").read_text().splitlines()]
    prov = [{"key": k, "task": r["Task"], "source": r["Source"], "verdict": v} for k, r, v in zip(keys, rows, verdicts)]
    prov += [{"key": e["key"], "task": e["task"], "source": e["source"], "verdict": "excluded"} for e in excluded]
    pd.DataFrame(prov).to_parquet(rel / "provenance.parquet")
    return tmp_path / name, keys


def test_rows_diff_verdict_value_options(tmp_path):
    rows = [row(task=DIM, rid=i) for i in range(3)]
    old, keys = _folder(tmp_path, "old", rows, [], ["retained", "corrected", "retained"])
    changed = [dict(rows[0]), dict(rows[1], Candidates={**rows[1]["Candidates"], "E": "9.00m"})]
    excluded = [{"key": keys[2], "task": DIM, "source": "ScanNet", "reason_codes": ["no_valid_options"]}]
    new, _ = _folder(tmp_path, "new", changed, excluded, ["retained", "retained"], keys=keys[:2])
    d = rows_diff(old, new).set_index("key")
    assert list(d.index) == [keys[1], keys[2]]  # row 0 unchanged
    assert d.loc[keys[1], "changed"] == "verdict, options"
    assert (d.loc[keys[1], "verdict before"], d.loc[keys[1], "verdict after"]) == ("corrected", "retained")
    assert d.loc[keys[2], "changed"] == "verdict, value, question, options"
    assert d.loc[keys[2], "reasons after"] == "no_valid_options" and d.loc[keys[2], "value after"] == ""


def test_large_effect_and_cells_by_hand():
    t = pd.DataFrame([
        # 14/27 = 51.9%: the exact 99% interval's lower end is about 0.28 > 0.2 -> large effect
        {"attack": "min", "family": "option", "task": DIM, "source": "ALL", "n_rows": 29, "picked": 27, "hits": 14.0,
         "accuracy": 14 / 27, "p_value": 0.001, "significant": "False", "underpowered": "True"},
        # 9/19: too few picked rows to call
        {"attack": "max", "family": "option", "task": DIM, "source": "ALL", "n_rows": 29, "picked": 19, "hits": 9.0,
         "accuracy": 9 / 19, "p_value": 0.01, "significant": "False", "underpowered": "True"},
        # 9/27 = 33%: below 35%
        {"attack": "median", "family": "option", "task": DIM, "source": "ALL", "n_rows": 29, "picked": 27,
         "hits": 9.0, "accuracy": 9 / 27, "p_value": 0.05, "significant": "False", "underpowered": "True"}])
    assert list(large_effects(t)) == [True, False, False]
    c = cells(t).iloc[0]
    assert c["strongest"] == "min" and c["large effect"] == "min 14/27" and not c["significant"] and c["underpowered"]
    # a table that flags large effects itself is believed
    assert list(large_effects(t.assign(large_effect=[False, True, False]))) == [False, True, False]


def test_update_baseline_change_and_revert(tmp_path):
    out = tmp_path / "out"
    rows = [row(task=DIM, rid=i) for i in range(2)]
    write_release(rows, [], out / "release")
    pd.DataFrame([{"key": json.loads(x)["Legacy Row Key"], "task": DIM, "source": "ScanNet", "verdict": "retained"}
                  for x in (out / "release" / "resti.jsonl").read_text().splitlines()]
                 ).to_parquet(out / "release" / "provenance.parquet")
    base = {"stages": {"03_dimensional": {"rule": {"abs_tol": 0.002}}}, "library": {}}
    assert update(out, base) is None and (out / BASELINE / "params.json").exists()  # the first run is the baseline
    assert update(out, base) is None and not (out / SUMMARY).exists()
    edited = {"stages": {"03_dimensional": {"rule": {"abs_tol": 0.3}}}, "library": {}}
    s = update(out, edited)
    assert s["params"][0]["param"] == "rule.abs_tol" and s["rows_changed"] == 0 and (out / SUMMARY).exists()
    assert update(out, base) is None and not (out / SUMMARY).exists()  # reverted: no section, no files
    assert update(out, edited, rebaseline=True) is None  # the edited run is the new baseline
    assert update(out, edited) is None


@pytest.mark.notebook
def test_tolerance_edit_names_param_rows_and_warning_and_revert_restores_bytes(main_run, dimensional_edit):
    ed = dimensional_edit  # decimals 2 -> 3 and rule.abs_tol 0.002 -> 0.3 in params/dimensional.yaml
    assert re.search(r"^rule: \{abs_tol: 0\.3,", ed.edit_params.read_text(), re.MULTILINE)

    # the changed rows, counted here from the two releases by key
    def rows(folder):
        acc = {json.loads(x)["Legacy Row Key"]: json.loads(x) for x in (folder / "release" / "resti.jsonl")
               .read_text().splitlines()}
        exc = {json.loads(x)["key"]: json.loads(x) for x in (folder / "release" / "excluded.jsonl")
               .read_text().splitlines()}
        return acc, exc

    (a0, e0), (a1, e1) = rows(main_run.out), rows(ed.edited)
    newly = sorted(k for k, e in e1.items() if k not in e0 and "no_valid_options" in e["reason_codes"])
    assert newly, "widening the Dimensional tolerance (its separation floor) leaves rows without valid options"
    changed = {k for k in a0 if k not in a1 or a0[k] != a1[k]}
    index = (ed.edited / "report" / "index.html").read_text(encoding="utf-8")
    section = index.split('<section id="changes">', 1)[1].split("</section>", 1)[0]
    assert "What changed" in section and "rule.abs_tol" in section and "03_dimensional" in section
    assert "decimals" in section
    assert f"<b>{len(changed)}</b> rows changed" in section
    for k in newly:
        assert k in section  # named in the warning
    assert "no_valid_options" in section and 'class="infeasible"' in section
    line = next(x for x in ed.edit_stdout.splitlines() if "what changed against the baseline run:" in x)
    assert "rule.abs_tol 0.002 -> 0.3" in line and "decimals 2 -> 3" in line, line
    assert f"{len(changed)} rows changed" in line, line
    table = pd.read_csv(ed.edited / "report" / "what_changed_rows.csv", dtype=str, keep_default_na=False)
    assert set(table["key"]) >= changed | set(newly)

    # reverted: the baseline's bytes, and no What changed files
    inc = ed.inc
    assert (inc / "report" / "index.html").read_bytes() == (main_run.out / "report" / "index.html").read_bytes()
    for sub in ("release", "tables"):
        names = sorted(p.name for p in (main_run.out / sub).iterdir())
        assert sorted(p.name for p in (inc / sub).iterdir()) == names
        for n in names:
            assert (inc / sub / n).read_bytes() == (main_run.out / sub / n).read_bytes(), n
    assert not list((inc / "report").glob("what_changed*"))
