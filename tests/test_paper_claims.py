"""The ReSTI report against what we measure: each measurement on hand-built evidence, the judging
rules, and (real data) the v5 figures recomputed here by a second method."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from resti_lib.report.paper import (
    LEAK,
    NOT_CHECKABLE,
    NOT_REPRODUCED,
    REPRODUCED,
    Claim,
    Measured,
    judge,
    legacy_claims,
    load_claims,
    panel,
    paper_split,
    v5_claims,
)
from resti_lib.tasks import names as task_names

ORI = "Ego-Centric Orientation"


def _ori_row(i, cands, answer, source="Waymo"):
    return {"Task": ORI, "Source": source, "Candidates": {k: f"{v:.2f}°" for k, v in zip("ABCDE", cands)},
            "Answer": answer, "ReSTI ID": f"r{i}"}


def test_claims_file_is_well_formed():
    claims = load_claims()
    assert len({c.id for c in claims}) == len(claims)
    from resti_lib.report.paper import MEASURES

    for c in claims:
        assert c.needs in ("v5", "legacy", "none"), c.id
        assert c.measure in MEASURES or c.needs == "none", c.id
        if c.needs != "none":
            assert c.value is not None, c.id
    # the report's task names, quoted in the claims, are registered tasks
    quoted = {c.args["task"] for c in claims if "task" in c.args}
    assert quoted <= set(task_names())
    assert paper_split() == {"recoverable": 182, "structural": 100}


def test_judge_counts_shares_and_bounds():
    c = Claim("x", "s", "c", "20.0% (37/185)", "m", "v5", value=[37, 185])
    assert judge(c, Measured((37.0, 185), "", "")) == REPRODUCED
    assert judge(c, Measured((38.0, 185), "", "")) == NOT_REPRODUCED
    share = Claim("x", "s", "c", "46.9%", "m", "legacy", value=46.9, decimals=1)
    assert judge(share, Measured(46.94, "", "")) == REPRODUCED and judge(share, Measured(46.86, "", "")) == REPRODUCED
    assert judge(share, Measured(47.0, "", "")) == NOT_REPRODUCED
    floor = Claim("x", "s", "c", "1°", "m", "v5", value=1.0, compare="at_least")
    assert judge(floor, Measured(1.0, "", "")) == REPRODUCED and judge(floor, Measured(0.99, "", "")) == NOT_REPRODUCED


def test_v5_measurements_on_a_hand_built_release():
    # three Waymo Orientation rows: smallest gap 1.0 (row 0: 0.0 vs 1.0; row 2 across the wrap), answer
    # ranks 2, 3, 2 -> per rank 0/2/1/0/0, spread 2
    rows = [_ori_row(0, [0.0, 1.0, -5.0, 7.0, 20.0], "A"),      # sorted -5, 0, 1, 7, 20: A (0.0) is rank 2
            _ori_row(1, [10.0, 3.0, -3.0, 40.0, -60.0], "B"),   # -60, -3, 3, 10, 40: B (3.0) is rank 3
            _ori_row(2, [179.5, -179.5, 90.0, -90.0, 0.0], "D")]  # -179.5, -90 (D), 0, 90, 179.5
    acc = pd.DataFrame(rows)
    exc = [{"task": ORI, "source": "Waymo", "verification_verdict": "exclusion_confirmed_object_match_none"},
           {"task": ORI, "source": "Waymo", "verification_verdict": "exclusion_confirmed_degenerate_time_window"},
           {"task": ORI, "source": "Waymo"}]
    att = pd.DataFrame([
        {"attack": "median", "family": "option", "task": ORI, "source": "ALL", "coverage": 1.0, "hits": 1.0,
         "picked": 3, "accuracy": 1 / 3, "significant": False},
        {"attack": "letter_order", "family": "option", "task": ORI, "source": "ALL", "coverage": 1.0, "hits": 3.0,
         "picked": 3, "accuracy": 1.0, "significant": True}])
    val = {"checks": {"separation": {"status": "fail", "n_failing": 1, "failing": ["r2"]},
                      "plausible_given_question": {"status": "fail", "n_failing": 2, "failing": ["r2", "r1"]}}}
    t = v5_claims(acc, exc, attacks=att, validation=val).set_index("id")
    assert t.loc["rows_total", "measured"] == "6" and t.loc["rows_total", "status"] == NOT_REPRODUCED
    assert t.loc["orientation_separation", "measured"] == "1.00°"
    assert t.loc["orientation_separation", "status"] == REPRODUCED
    assert t.loc["orientation_wrapped", "measured"] == "0"
    assert t.loc["orientation_rank_balance", "measured"] == "spread 2 (Waymo: 0/2/1/0/0)"
    assert t.loc["orientation_median", "measured"] == "1/3 = 33.3%"
    assert t.loc["exclusions_recoverable", "measured"] == "1"  # object_match_none
    assert t.loc["exclusions_structural", "measured"] == "2"   # degenerate window, and the unverified row
    assert t.loc["options_separated", "measured"] == "2"       # r1 and r2, each once
    assert t.loc[f"leak:{ORI}", "status"] == LEAK and t.loc[f"leak:{ORI}", "measured"] == "3/3 = 100.0%"
    # without v5 every v5 claim says why it cannot be checked
    none = v5_claims(None, None, why_not="the audited release is not ReSTI v5")
    assert set(none["status"]) == {NOT_CHECKABLE} and set(none["how"]) == {"the audited release is not ReSTI v5"}


def test_legacy_claims_only_on_real_input():
    tables = {"key_detail_breakdown": pd.DataFrame({"cause": ["mismatches, the ReSTI report's definition: x",
                                                              "structured record", "scalar disagreeing"],
                                                    "rows": [1014, 315, 173]}),
              "answer_layer_defects": pd.DataFrame({"task": ["T", "Total"], "duplicate_options_exact": [32, 32]}),
              "verdicts": pd.DataFrame({"task": ["Total"], "retained": [652], "corrected": [547],
                                        "re-contracted": [583]})}
    real = legacy_claims(tables, real=True).set_index("id")
    for i in ("key_detail", "key_detail_structured", "key_detail_scalar", "duplicates_exact", "verdict_retained",
              "verdict_corrected", "verdict_recontracted"):
        assert real.loc[i, "status"] == REPRODUCED, i
    assert real.loc["duplicates_numeric", "status"] == NOT_REPRODUCED  # no column: 0 rows
    assert real.loc["legacy_median", "status"] == NOT_CHECKABLE       # its table was not given
    synthetic = legacy_claims(tables, real=False).set_index("id")
    assert set(synthetic["status"]) == {NOT_CHECKABLE}
    assert synthetic.loc["key_detail", "how"].endswith("on this run's synthetic legacy benchmark: 1,014")
    assert synthetic.loc["earlier_median", "how"] == "the earlier revision of the options is not published"
    both = panel(synthetic.reset_index(), v5_claims(None, None, why_not="x"))
    assert list(both["id"][:3]) == ["rows_total", "rows_accepted", "rows_excluded"]


@pytest.mark.shared
def test_v5_figures_by_a_second_method(resti_v5_dir):
    """The Orientation median pick and best fixed rank counted here from the candidates, the split
    counted from the verdicts: the panel's figures are these."""
    from resti_lib import values as V
    from resti_lib.io.benchmark import load_release
    from resti_lib.release.audit import attack_release

    acc = [json.loads(x) for x in (resti_v5_dir / "resti.jsonl").read_text().splitlines() if x.strip()]
    exc = [json.loads(x) for x in (resti_v5_dir / "excluded.jsonl").read_text().splitlines() if x.strip()]
    ranks = [0] * 5
    for r in acc:
        if r["Task"] == ORI:
            v = {k: V.parse(s).value for k, s in r["Candidates"].items()}
            ranks[sorted(v, key=v.get).index(r["Answer"])] += 1
    assert ranks[2] == 37 and max(ranks) == 38 and sum(ranks) == 185  # the report: 20.0% and 20.5%
    referent = {"exclusion_confirmed_object_match_ambiguous", "exclusion_confirmed_object_match_none",
                "exclusion_confirmed_no_source_instance", "exclusion_confirmed_ambiguous_instance",
                "exclusion_confirmed_ambiguous_camera_or_object_referent"}
    recoverable = sum(r.get("verification_verdict") in referent for r in exc)
    assert (recoverable, len(exc) - recoverable) == (182, 100)

    rel = load_release(resti_v5_dir, strict=False)
    run = attack_release(rel, families=["option"])
    t = v5_claims(rel.accepted, rel.excluded, attacks=run.table).set_index("id")
    assert t.loc["orientation_median", "measured"] == "37/185 = 20.0%"
    assert t.loc["orientation_rank", "measured"] == "38/185 = 20.5%"
    assert (t.loc["exclusions_recoverable", "measured"], t.loc["exclusions_structural", "measured"]) == ("182", "100")
    assert t.loc["grounding_attack", "status"] == NOT_REPRODUCED  # our option family beats 22.61%
    leak = t.loc[f"leak:{ORI}"]
    assert leak["measured"] == "117/185 = 63.2%" and leak["how"].startswith("letter_order")
