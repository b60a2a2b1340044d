"""Option-only attacks on hand-built rows with hand-computed picks; statistics by hand."""

import json
from math import comb

import pandas as pd
import pytest

from resti_lib.options.attacks import attack_table, binom_p, holm, parse_rows, run_picks
from tests.helpers import row


def picks_of(rows, names):
    df = run_picks(parse_rows(rows), names)
    return {(r.attack, r.rid): (None if pd.isna(r.pick) else r.pick) for r in df.itertuples()}


def test_rank_mean_medoid_picks():
    r = row(cands={"A": "3.00m", "B": "1.00m", "C": "5.00m", "D": "2.00m", "E": "4.00m"}, answer="A")
    p = picks_of([r], ["min", "rank_2", "median", "rank_4", "max", "nearest_mean", "medoid"])
    assert p[("min", 0)] == "B" and p[("rank_2", 0)] == "D" and p[("median", 0)] == "A"
    assert p[("rank_4", 0)] == "E" and p[("max", 0)] == "C"
    assert p[("nearest_mean", 0)] == "A" and p[("medoid", 0)] == "A"


def test_ranks_use_si_values_across_units():
    # 150cm = 1.5m is the largest; 0.9m the smallest
    r = row(cands={"A": "150cm", "B": "1.20m", "C": "0.90m", "D": "1.00m", "E": "1.10m"}, answer="A")
    p = picks_of([r], ["min", "max"])
    assert p[("max", 0)] == "A" and p[("min", 0)] == "C"


def test_circular_mean_wraps():
    r = row(task="Ego-Centric Orientation",
            cands={"A": "170.00°", "B": "-170.00°", "C": "175.00°", "D": "-175.00°", "E": "-180.00°"},
            answer="E")
    p = picks_of([r], ["nearest_circular_mean", "nearest_mean"])
    assert p[("nearest_circular_mean", 0)] == "E"  # the circular mean is 180°
    assert p[("nearest_mean", 0)] != "E"  # the linear mean (-36°) is fooled by the wrap


def test_ties_abstain():
    r = row(cands={"A": "1.00m", "B": "22.00m", "C": "3.00m", "D": "44.00m", "E": "5.00m"}, answer="A")
    p = picks_of([r], ["shortest_string", "longest_string"])
    assert p[("shortest_string", 0)] is None  # A, C, E all 5 characters
    assert p[("longest_string", 0)] is None   # B, D tie at 6


def test_constant_letter_and_binomial():
    rows = [row(rid=i, answer=a) for i, a in enumerate("AAB")]
    t = attack_table(rows, attacks=["constant_letter"])
    allrow = t[(t["source"] == "ALL")].iloc[0]
    assert allrow["hits"] == 2 and allrow["picked"] == 3
    # P[X>=2 | n=3, 1/5] = 3*(1/5)^2*(4/5) + (1/5)^3 = 0.104, times 5 letters (Bonferroni)
    assert allrow["p_value"] == pytest.approx(min(1.0, 5 * 0.104))


def test_label_prior_is_leave_one_out():
    cands = {"A": "Front", "B": "Left", "C": "Right", "D": "Front-Left", "E": "Front-Right"}
    rows = [row(task="Spatial Relation", source="Waymo", rid=i, cands=cands, answer=a)
            for i, a in enumerate(["A", "A", "B"])]
    p = picks_of(rows, ["label_prior"])
    assert p[("label_prior", 0)] is None   # others: Front 1, Left 1 -> tie
    assert p[("label_prior", 2)] == "A"    # others: Front 2 -> picks Front, wrong


def _box(c, lwh=(1, 1, 1)):
    return json.dumps({"C_central_point": list(c), "C_heading": 0.0, "C_lwh": list(lwh),
                       "C_rotation_camera_from_box": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})


def test_field_majority_reveals_one_field_perturbations():
    cands = {"A": _box((0, 0, 0)), "B": _box((1, 0, 0)), "C": _box((0, 1, 0)), "D": _box((0, 0, 1)),
             "E": _box((2, 2, 2))}
    r = row(task="3D Video Grounding", cands=cands, answer="A")
    p = picks_of([r], ["field_majority", "centroid_center"])
    assert p[("field_majority", 0)] == "A"
    # centroid of centres = (0.6, 0.6, 0.6): distances A 1.039, B/C/D 0.825 (tie) -> abstain
    assert p[("centroid_center", 0)] is None


def test_binom_p_by_hand():
    n, k = 10, 4
    want = sum(comb(n, i) * 0.2 ** i * 0.8 ** (n - i) for i in range(k, n + 1))
    assert binom_p(k, n) == pytest.approx(want)
    assert binom_p(0, 10) == pytest.approx(1.0)


def test_holm_by_hand():
    assert holm([0.01, 0.04, 0.03], 0.05) == [True, False, False]
    assert holm([0.01, 0.02, 0.03], 0.05) == [True, True, True]  # 0.01<=.0167, .02<=.025, .03<=.05


def test_v5_orientation_matches_report(resti_v5_dir):
    rows = [json.loads(l) for l in open(resti_v5_dir / "resti.jsonl", encoding="utf-8")]
    t = attack_table(rows)
    o = t[(t["task"] == "Ego-Centric Orientation") & (t["source"] == "ALL")].set_index("attack")
    assert (o.loc["median", "hits"], o.loc["median", "picked"]) == (37, 185)
    best_rank = o.loc[["min", "rank_2", "median", "rank_4", "max"], "hits"].max()
    assert best_rank == 38
    assert not o["significant"].any()
