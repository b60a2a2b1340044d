"""Option-only attacks on hand-built rows with hand-computed picks; statistics by hand or by a second method."""

import itertools
import json
from collections import Counter
from math import comb

import numpy as np
import pandas as pd
import pytest

from resti_lib.options.attacks import (
    attack_table,
    binom_p,
    headline,
    holm,
    holm_adjusted,
    parse_rows,
    run_picks,
    select,
    tie_aware_p,
    tie_aware_p_counts,
)
from resti_lib.report.statistics import critical_hits, min_detectable_accuracy
from resti_lib.tasks import interface as _interface
from tests.helpers import row

IFACE = _interface()

IFACE = _interface()


def picks_of(rows, names, direction=""):
    df = run_picks(parse_rows(rows), names, records=rows)
    df = df[df["direction"].isin(["", direction])]
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
    assert "E" not in p[("nearest_mean", 0)]  # the linear mean (-36°) is fooled by the wrap


def test_ties_are_scored_by_expected_accuracy():
    r = row(cands={"A": "1.00m", "B": "22.00m", "C": "3.00m", "D": "44.00m", "E": "5.00m"}, answer="A")
    df = run_picks(parse_rows([r]), ["shortest_string", "longest_string"], records=[r]).set_index("attack")
    assert df.loc["shortest_string", "pick"] == "ACE" and df.loc["shortest_string", "tied"] == 3
    assert df.loc["shortest_string", "hit"] == pytest.approx(1 / 3)  # the answer is one of three tied
    assert df.loc["longest_string", "pick"] == "BD" and df.loc["longest_string", "hit"] == 0.0
    # a rank tie: 1.00m twice at the bottom -> both are "min"
    r2 = row(cands={"A": "1.00m", "B": "100cm", "C": "3.00m", "D": "4.00m", "E": "5.00m"}, answer="B")
    assert picks_of([r2], ["min"])[("min", 0)] == "AB"


def test_constant_letter_and_binomial():
    rows = [row(rid=i, answer=a) for i, a in enumerate("AAB")]
    t = attack_table(iface=IFACE, records=rows, attacks=["constant_letter"])
    allrow = t[(t["source"] == "ALL")].iloc[0]
    assert allrow["hits"] == 2 and allrow["picked"] == 3
    # P[X>=2 | n=3, 1/5] = 3*(1/5)^2*(4/5) + (1/5)^3 = 0.104, times 5 letters (Bonferroni)
    assert allrow["p_value"] == pytest.approx(min(1.0, 5 * 0.104))


def test_label_prior_is_the_best_constant_label():
    cands = {"A": "Front", "B": "Left", "C": "Right", "D": "Front-Left", "E": "Front-Right"}
    rows = [row(task="Spatial Relation", source="Waymo", rid=i, cands=cands, answer=a)
            for i, a in enumerate(["A", "A", "B"])]
    assert picks_of(rows, ["label_prior"], direction="Front")[("label_prior", 2)] == "A"
    t = attack_table(iface=IFACE, records=rows, attacks=["label_prior"]).set_index("source")
    # Front is the answer twice of three: P[X >= 2 | n=3, 1/5] = 0.104, times 5 labels tried (Bonferroni)
    assert t.loc["Waymo", "direction"] == "Front" and t.loc["Waymo", "hits"] == 2
    assert t.loc["Waymo", "p_value"] == pytest.approx(5 * 0.104)


def test_label_prior_test_is_exact_on_uniform_labels():
    """A majority vote that leaves one row out shares its rows' luck (its p-values are far too small on
    uniform labels); the best constant label with a Bonferroni factor is exact: checked by simulation."""
    rng = np.random.default_rng(11)
    labels = ["Front", "Front-Left", "Front-Right", "Left", "Right"]
    small = 0
    for _rep in range(60):
        rows = []
        for i in range(60):
            order = rng.permutation(5)
            cands = {k: labels[j] for k, j in zip("ABCDE", order)}
            rows.append(row(task="Spatial Relation", source="Waymo", rid=i, cands=cands,
                            answer="ABCDE"[rng.integers(5)]))
        t = attack_table(iface=IFACE, records=rows, attacks=["label_prior"])
        small += int(t[t["source"] == "Waymo"]["p_value"].iloc[0] < 0.1)
    assert small <= 6 + 4  # at most 10% of 60 below 0.1, plus sampling slack (binomial sd 2.3)


def _box(c, lwh=(1, 1, 1)):
    return json.dumps({"C_central_point": list(c), "C_heading": 0.0, "C_lwh": list(lwh),
                       "C_rotation_camera_from_box": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})


def test_field_majority_reveals_one_field_perturbations():
    cands = {"A": _box((0, 0, 0)), "B": _box((1, 0, 0)), "C": _box((0, 1, 0)), "D": _box((0, 0, 1)),
             "E": _box((2, 2, 2))}
    r = row(task="3D Video Grounding", cands=cands, answer="A")
    p = picks_of([r], ["field_majority", "centroid_center"])
    assert p[("field_majority", 0)] == "A"
    # centroid of centres = (0.6, 0.6, 0.6): distances A 1.039, B/C/D 0.825 (a tie of three)
    assert p[("centroid_center", 0)] == "BCD"


def test_letter_order_finds_distractors_listed_outwards():
    # distractors 1.2, 1.4, 1.6, 1.8 listed in letter order, the answer 1.0 inserted at C: seen from C the
    # other four get steadily farther (+6 concordant pairs); from any other candidate they do not
    rows = []
    for i, pos in enumerate([2, 0, 4, 1, 3, 2]):
        vals = [1.2, 1.4, 1.6, 1.8]
        vals.insert(pos, 1.0)
        # one recording per row: rows of one recording offering one set, answered at one place, are one draw
        rows.append(row(rid=i, video=f"scene09{i:02d}_00.mp4", cands={k: f"{v:.2f}m" for k, v in zip("ABCDE", vals)},
                        answer="ABCDE"[pos]))
    p = picks_of(rows, ["letter_order"], direction="max")
    assert all(p[("letter_order", i)] == r["Answer"] for i, r in enumerate(rows))
    t = attack_table(iface=IFACE, records=rows, attacks=["letter_order"]).set_index("source")
    # the table keeps the best of the 5 directions: 6/6 hits, p = 5 * 0.2**6 (Bonferroni over directions)
    assert t.loc["ScanNet", "direction"] == "max" and t.loc["ScanNet", "hits"] == 6
    assert t.loc["ScanNet", "p_value"] == pytest.approx(5 * 0.2 ** 6)


def test_label_order_finds_the_inserted_label():
    canon = ["Left", "Right", "Closer", "Farther", "Directly above"]
    rows = []
    rng = np.random.default_rng(3)
    for i in range(12):
        ans = canon[rng.integers(5)]
        rest = [x for x in canon if x != ans]
        pos = int(rng.integers(5))
        seq = rest[:pos] + [ans] + rest[pos:]
        rows.append(row(task="Spatial Relation", source="Omni6DPose", rid=i, cands=dict(zip("ABCDE", seq)),
                        answer="ABCDE"[pos]))
    df = run_picks(parse_rows(rows), ["label_order"], records=rows)
    # the inserted label is always in the picked set: removing it restores the usual order
    assert all(r.answer in r.pick for r in df.itertuples())
    assert df["hit"].mean() > 0.45  # ties: an answer put back at its usual place, or next to it


def test_binom_p_by_hand():
    n, k = 10, 4
    want = sum(comb(n, i) * 0.2 ** i * 0.8 ** (n - i) for i in range(k, n + 1))
    assert binom_p(k, n) == pytest.approx(want)
    assert binom_p(0, 10) == pytest.approx(1.0)


def _enumerated_p(hits: float, ties: list, clusters: tuple | list = ()) -> float:
    """P[sum of scores >= hits] by enumerating every hit/miss pattern of the single rows and every place of
    the answer in each cluster's set (a second method); a cluster is a list of picked place sets."""
    total = 0.0
    for places in itertools.product(range(5), repeat=len(clusters)):
        c_score = sum(sum(1 / len(pk) for pk in cl if u in pk) for u, cl in zip(places, clusters))
        for pattern in itertools.product([0, 1], repeat=len(ties)):
            prob, score = 0.2 ** len(clusters), c_score
            for hit, k in zip(pattern, ties):
                prob *= (k / 5) if hit else (1 - k / 5)
                score += hit / k
            if score >= hits - 1e-9:
                total += prob
    return total


@pytest.mark.parametrize("ties,hits", [([1, 1, 2, 3, 4, 5, 2, 1], 3.0), ([2, 2, 2, 3, 3, 4, 1, 1, 5, 5], 2.5),
                                       ([1] * 9, 4.0), ([3, 3, 3, 4, 4, 2, 1], 7 / 3), ([5, 5, 5], 0.6)])
def test_tie_aware_p_matches_enumeration(ties, hits):
    assert tie_aware_p(hits, ties) == pytest.approx(_enumerated_p(hits, ties), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("ties,clusters,hits", [
    ([1, 1, 2], [[{0}, {0}], [{1}, {1}, {1}]], 3.0),           # rows of a cluster pick one place: all or none
    ([1, 3, 5], [[{0}, {1}], [{2, 3}, {2}]], 2.0),             # they pick different places, and ties
    ([], [[{4}, {4}], [{4}, {4}], [{0}, {0}]], 4.0),           # clusters alone: P = 1 - P[at most one hit] = 0.104
])
def test_tie_aware_p_with_clusters_matches_enumeration(ties, clusters, hits):
    """A cluster of coupled rows is one draw: the answer sits at one of the five places of the set, each
    with probability 1/5, and each of its rows scores by its own pick at that place."""
    scores = [[sum(60 // len(pk) for pk in cl if u in pk) for u in range(5)] for cl in clusters]
    got = tie_aware_p_counts(hits, Counter(ties), scores)
    assert got == pytest.approx(_enumerated_p(hits, ties, clusters), rel=1e-9, abs=1e-12)
    if not ties:
        assert got == pytest.approx(1 - 0.8 ** 3 - 3 * 0.2 * 0.8 ** 2, rel=1e-9)


def _coupled_release(n_rec: int = 40, seed: int = 2):
    """``n_rec`` recordings of three displacement rows each: a path length, a displacement whose set is the path's
    times 0.8 (printed to the centimetre, letters shuffled anew) with its answer at the same place, and a row of
    its own draw. The answer's place is uniform per recording."""
    rng = np.random.default_rng(seed)
    rows, place = [], []
    for r in range(n_rec):
        base = np.sort(rng.uniform(1.0, 10.0, 5))
        u = int(rng.integers(5))
        place.append(u)
        for j, vals in enumerate((base, 0.8 * base, np.sort(rng.uniform(1.0, 10.0, 5)))):
            letters = list(rng.permutation(list("ABCDE")))
            cands = {k: f"{v:.2f}m" for k, v in zip(letters, vals)}
            ans = letters[u] if j < 2 else letters[int(rng.integers(5))]
            rows.append(row(video=f"scene{r:04d}_00.mp4", rid=3 * r + j, cands=cands, answer=ans,
                            question=["What is the path length?", "What is the displacement?",
                                      "What is the displacement?"][j]))
    return rows, place


def test_coupled_rows_count_as_one_draw():
    """The path-length row and the scaled displacement row of each recording are one cluster (read from the
    strings alone), the third row alone; the smallest-candidate rule's p-value is then the binomial over
    recordings of the pairs' shared hits plus the single rows' hits, summed here by a direct convolution."""
    from scipy.stats import binom as B

    from resti_lib.options.attacks.batch import make_batch

    rows, place = _coupled_release()
    batch, _ = make_batch(parse_rows(rows), rows, iface=IFACE)
    cluster, slots = batch.coupled()
    assert all(cluster[3 * r] is not None and cluster[3 * r] == cluster[3 * r + 1] for r in range(40))
    assert len({cluster[3 * r] for r in range(40)}) == 40 and all(cluster[3 * r + 2] is None for r in range(40))
    for i, r in enumerate(rows):  # the slots order the letters by value
        vals = {k: float(v[:-1]) for k, v in r["Candidates"].items()}
        assert slots[i] == "".join(sorted(vals, key=vals.get))
    t = attack_table(rows, iface=IFACE, attacks=["min"])
    cell = t[(t["attack"] == "min") & (t["source"] == "ScanNet")].iloc[0]
    pair_hits = sum(u == 0 for u in place)
    single_hits = sum(r["Candidates"][r["Answer"]] == min(r["Candidates"].values(), key=lambda v: float(v[:-1]))
                      for r in rows[2::3])
    assert cell["hits"] == 2 * pair_hits + single_hits
    assert (cell["picked"], cell["draws"]) == (120, 80)  # 40 pairs, one draw each, and 40 rows alone
    # P[2 X + Y >= hits], X ~ Bin(40, 1/5) pairs, Y ~ Bin(40, 1/5) single rows
    want = sum(B.pmf(x, 40, 0.2) * B.sf(cell["hits"] - 2 * x - 1, 40, 0.2) for x in range(41))
    assert cell["p_value"] == pytest.approx(want, rel=1e-9)
    # not the binomial over 120 independent rows
    assert cell["p_value"] != pytest.approx(B.sf(cell["hits"] - 1, 120, 0.2), rel=1e-3)


def test_holm_by_hand():
    assert holm([0.01, 0.04, 0.03], 0.05) == [True, False, False]
    assert holm([0.01, 0.02, 0.03], 0.05) == [True, True, True]  # 0.01<=.0167, .02<=.025, .03<=.05
    # adjusted: sorted .01 .03 .04 -> 3*.01=.03, max(.03, 2*.03)=.06, max(.06, .04)=.06
    assert holm_adjusted([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])


def test_power_by_hand():
    # Binomial(25, 0.2): P[X >= 9] = 0.0468 <= 0.05 < P[X >= 8] = 0.109, so the test rejects at 9 hits
    assert critical_hits(25, 0.05) == 9
    q = min_detectable_accuracy(25, 0.05)

    def power(acc):  # P[Binomial(25, acc) >= 9], summed by hand
        return sum(comb(25, i) * acc ** i * (1 - acc) ** (25 - i) for i in range(9, 26))
    assert power(q) == pytest.approx(0.8, abs=1e-4)
    assert power(q - 0.01) < 0.8 < power(q + 0.01)
    assert np.isnan(min_detectable_accuracy(3, 1e-4))  # three rows cannot reach 1e-4


def test_table_states_power_per_cell():
    rows = [row(rid=i, answer="ABCDE"[i % 5], cands={k: f"{(j + 1) * (i + 1) / 10:.2f}m" for j, k in
                                                     enumerate("ABCDE")}) for i in range(40)]
    t = attack_table(iface=IFACE, records=rows)
    level = 0.05 / len(t)
    assert np.allclose(t["min_detectable"], min_detectable_accuracy(40, level))
    assert t["underpowered"].all()  # 40 rows cannot detect a 35% blind accuracy at this level
    assert (t["p_holm"] >= t["p_value"]).all()


def test_select_and_unknown_names():
    assert "letter_order" in select(None) and "learned_blind" in select(None)
    assert "learned_blind" not in select(None, fast=True)
    assert set(select("metadata")) == {"metadata_label", "metadata_value"}
    with pytest.raises(ValueError, match="unknown attack family"):
        select("colour")
    with pytest.raises(ValueError, match="unknown attack"):
        select(None, ["nope"])


@pytest.mark.shared
def test_v5_orientation_matches_report(resti_v5_dir):
    rows = [json.loads(line) for line in (resti_v5_dir / "resti.jsonl").read_text(encoding="utf-8").splitlines()]
    ranks = ["min", "rank_2", "median", "rank_4", "max"]
    t = attack_table(iface=IFACE, records=rows, attacks=ranks)
    o = t[(t["task"] == "Ego-Centric Orientation") & (t["source"] == "ALL")].set_index("attack")
    assert (o.loc["median", "hits"], o.loc["median", "picked"]) == (37, 185)
    assert o.loc[ranks, "hits"].max() == 38
    assert not o["significant"].any()


@pytest.mark.shared
def test_v5_letter_order_reveals_the_answer(resti_v5_dir):
    """The report's rank attacks miss it, but v5's scalar distractors are listed in the order they were
    generated around the answer. Counted here by a second method: the answer is the one candidate from
    which the other four, in letter order, are strictly farther and farther (or nearer and nearer)."""
    from resti_lib import values as V

    rows = [json.loads(line) for line in (resti_v5_dir / "resti.jsonl").read_text(encoding="utf-8").splitlines()]
    rows = [r for r in rows if r["Task"] == "Ego-Centric Orientation"]
    monotone = 0
    for r in rows:
        x = [V.parse(r["Candidates"][k]).value for k in "ABCDE"]
        a = "ABCDE".index(r["Answer"])
        d = [abs(x[j] - x[a]) for j in range(5) if j != a]
        monotone += all(d[i] < d[i + 1] for i in range(3)) or all(d[i] > d[i + 1] for i in range(3))
    assert monotone > 100  # of 185: chance for one candidate is 2/24
    t = headline(attack_table(iface=IFACE, records=rows, families="option"))
    cell = t.set_index("source").loc["ALL"]
    assert cell["significant"] and cell["attack"] == "letter_order" and cell["accuracy"] > 0.55


def test_nearest_questions_match_brute_force():
    from resti_lib.options.attacks.question import nearest_questions

    rng = np.random.default_rng(5)
    vocab = [f"w{i}" for i in range(12)]
    sets = [frozenset(rng.choice(vocab, size=rng.integers(1, 6), replace=False)) for _ in range(90)]
    got = nearest_questions(sets, k=5, block=16)  # several blocks
    for i, s in enumerate(sets):
        sims = sorted(((len(s & t) / len(s | t), -j) for j, t in enumerate(sets) if j != i), reverse=True)[:5]
        assert got[i] == [-x[1] for x in sims]


def test_printed_in_agrees_with_a_boundary_regex():
    """The cross-row reader's verbatim match (a scan) against the regex it stands for, on random strings
    drawn from an alphabet of digits, points, signs and brackets, so boundaries are hit often."""
    import random
    import re

    from resti_lib.options.attacks.features import printed_in

    rnd = random.Random(7)
    alphabet = "012.-(m"
    hits = 0
    for _ in range(4000):
        s = "".join(rnd.choice(alphabet) for _ in range(rnd.randint(1, 4)))
        text = "".join(rnd.choice(alphabet) for _ in range(rnd.randint(0, 30)))
        expect = re.search(r"(?<![\d.])" + re.escape(s) + r"(?!\d)", text) is not None
        assert printed_in(s, text) == expect, (s, text)
        hits += expect
    assert 400 < hits < 3600  # both outcomes are exercised
    assert printed_in("1.25", "moved1.25m") and not printed_in("1.25", "moved11.25m")
    assert not printed_in("1.25", "1.250m") and printed_in("1.25", "at1.25.")


def test_population_forest_is_quiet_when_the_host_cleared_its_warning_filters():
    """The population attacker's forest grows its trees on joblib threads, which take the caller's
    warning filters; with none at all (a host that cleared them) the library warns once per tree (a
    bare forest here: 10 warnings). The attacker's fits warn nothing."""
    import warnings

    from sklearn.ensemble import RandomForestClassifier

    from resti_lib.options.attacks.learned import LearnedConfig, _population_model, grouped_scores

    rng = np.random.default_rng(0)
    X, y = rng.random((200, 3)), np.zeros(200, bool)
    y[::5] = True
    with warnings.catch_warnings(record=True) as bare:
        warnings.resetwarnings()
        RandomForestClassifier(n_estimators=10, n_jobs=2).fit(X, y)
    with warnings.catch_warnings(record=True) as ours:
        warnings.resetwarnings()
        grouped_scores(X, y, [i % 8 for i in range(40)], LearnedConfig(), make_model=_population_model)
    assert sum("parallel.delayed" in str(w.message) for w in bare) == 10
    assert [str(w.message) for w in ours] == []
