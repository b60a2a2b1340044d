"""The channels of the attack suite that read several rows of one recording, the direction of travel,
formatting tie sets, release-wide priors and population-relative features: each finds its own leak planted
in a synthetic release of recordings (tests/attack_release.py, ``recording_rows``), no family false-alarms
on the clean control, the large-effect flag and the headline, and the channels on the real ReSTI v5.
Expected accuracies come from the plant (by hand) or are counted from the strings by a second method."""

import json
import re
from collections import Counter

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binom

from resti_lib import LETTERS
from resti_lib.options.attacks import (
    ATTACKS,
    FAMILIES,
    LARGE_EFFECT_AT,
    LARGE_EFFECT_MIN_ROWS,
    attack_table,
    headline,
    large_effects,
)
from resti_lib.options.learned import LearnedConfig
from resti_lib.tasks import interface as _interface
from tests.attack_release import N_RECORDINGS, POSE_RECORDINGS, POSE_ROWS, RECORDING_PLANTS, recording_rows

IFACE = _interface()
FAST_LEARNED = LearnedConfig(max_iter=40, learning_rate=0.15, population_trees=30)
NEW_FAMILIES = ("format", "prior", "question", "relation", "keyed")

D, S = "Displacement & Path Length", "Speed & Acceleration"
# plant -> (family, attack, {task it plants into: least accuracy there, None: counted by a second method})
PLANTED = {
    # relations (a keyed reader, who reads the sibling's answer; the blind versions are checked below):
    # the planted value is the sibling's value by arithmetic, printed; the answer is the
    # candidate nearest to it in every planted row (1.0 by construction; the rounding of the printed
    # sibling, 0.01 m, can let a distractor within one print unit win now and then). A speed reveals the
    # displacement rows of its cell, not its path-length rows: (60 + 60/5) / 120 = 0.6 there, by hand
    "rate_window": ("keyed", "keyed_rate_window", {S: 0.95, D: 0.5}),
    "path_length": ("keyed", "keyed_path_length", {"Trajectory Description": 0.95, D: 0.95}),
    # the displacement is at most the path length asked beside it and near it: the largest displacement
    # within the path picks it, and the shortest path beyond the displacement picks the path (exactly
    # counted by test_distance_bound_hits_counted_from_the_strings)
    "distance_bound": ("keyed", "keyed_distance_bound", {D: 0.6}),
    "turn_sum": ("keyed", "keyed_turn_sum", {"Ego-Centric Orientation": 0.95, "Trajectory Description": 0.95}),
    "box_edge": ("keyed", "keyed_box_edge", {"Dimensional Measurement": 0.95, "3D Video Grounding": 0.95}),
    # every pose of a segment lies on one straight track at a constant speed: seven known poses per row
    "pose_track": ("keyed", "keyed_pose_track", {"Pose Estimation": 0.95}),
    "converse": ("keyed", "keyed_converse", {"Spatial Relation": 1.0}),
    # the answer lies exactly along the camera's x axis; no random distractor direction does
    "travel_direction": ("question", "travel_direction", {"Pose Estimation": 1.0}),
    "fewest_significant": ("format", "fmt_fewest_significant", {S: None}),
    "shortest": ("format", "fmt_shortest", {S: None}),
    "last_digit": ("format", "fmt_last_digit", {S: None}),
    # half of a pool of strings are answers, the other half distractors: the rate learned on the other
    # half of the recordings tells them apart wherever the answer string was seen there
    "string_rate": ("prior", "string_rate", {"Dimensional Measurement": 0.9}),
    "field_rate": ("prior", "field_rate", {"3D Video Grounding": 0.8}),
    # the answer's box centre sits within 5% of the distractors' spread of the middle: every field says so
    "field_density": ("prior", "field_density", {"3D Video Grounding": 0.8}),
    # slow scenes answer their smallest candidate, fast ones their largest: min and max get half each
    "nearest_set": ("prior", "nearest_set", {S: 0.9}),
}


def _cell(t, name, task):
    return t[(t["attack"] == name) & (t["task"] == task) & (t["source"] != "ALL")].iloc[0]


def _tie_set_accuracy(rows, task, score) -> float:
    """The expected accuracy of picking, in every row of ``task``, the candidates of highest ``score(string)``
    (a second method: the score is computed from the strings here, not by the attack)."""
    acc = []
    for r in rows:
        if r["Task"] != task:
            continue
        s = {k: score(v) for k, v in r["Candidates"].items()}
        best = [k for k, v in s.items() if v == max(s.values())]
        acc.append(1 / len(best) if r["Answer"] in best else 0.0)
    return float(np.mean(acc))


def _significant_digits(s: str) -> int:
    """Significant digits of a printed number without its trailing zeros, through the shortest float form."""
    return len(f"{float(re.sub(r'[^0-9.]', '', s)):g}".replace(".", "").lstrip("0"))


SECOND_METHOD = {
    "fewest_significant": lambda s: -_significant_digits(s),
    "shortest": lambda s: -len(s),
    "last_digit": lambda s: float(re.sub(r"[^0-9]", "", s)[-1] == "7"),
}


@pytest.mark.parametrize("plant", RECORDING_PLANTS)
def test_family_finds_its_planted_channel(plant):
    family, name, cells = PLANTED[plant]
    rows = recording_rows(plant, seed=0)
    t = attack_table(rows, iface=IFACE, families=family)
    for task, least in cells.items():
        hit = _cell(t, name, task)
        assert hit["family"] == family and hit["significant"], hit
        if least is None:
            assert hit["accuracy"] == pytest.approx(_tie_set_accuracy(rows, task, SECOND_METHOD[plant]))
        else:
            assert hit["accuracy"] >= least, hit
    # the plant changes its cells only: the family finds nothing elsewhere
    others = t[t["significant"] & ~t["task"].isin(set(cells))]
    assert others.empty, others[["attack", "task", "source", "accuracy"]]


@pytest.mark.parametrize("plant", ["rate_window", "path_length", "distance_bound", "turn_sum", "box_edge"])
def test_blind_relations_find_a_plant_from_the_siblings_candidates(plant):
    """A blind reader sees a sibling's five candidates, not its key: the planted answer is the candidate
    that the relation pairs with one of them (the distractors, drawn apart, pair with none), so the blind
    attack finds the plant too, less surely than a keyed reader."""
    family, name, cells = PLANTED[plant]
    t = attack_table(recording_rows(plant, seed=0), iface=IFACE, families="relation")
    for task in cells:
        hit = _cell(t, name.replace("keyed_", "rel_"), task)
        # a bound read off five path candidates keeps every displacement within one of them: a weaker pick
        assert hit["significant"] and hit["accuracy"] > (0.3 if plant == "distance_bound" else 0.4), hit


def test_planted_rate_reveals_every_speed_row():
    """Speed = displacement / window where a displacement sibling shares the window: all 60 speed rows (one
    may lose to a distractor within a print unit)."""
    t = attack_table(recording_rows("rate_window", seed=0), iface=IFACE, families="keyed")
    assert _cell(t, "keyed_rate_window", S)["hits"] >= N_RECORDINGS - 1
    disp = _cell(t, "keyed_rate_window", D)
    assert disp["picked"] == 2 * N_RECORDINGS and 0.5 < disp["accuracy"] < 0.7


def test_distance_bound_hits_counted_from_the_strings():
    """keyed_distance_bound's hits counted a second way, from the printed strings of each recording: the
    largest displacement candidate not above a path over the window (the path length's answer, or the
    total of the trajectory description's answer: a tie of both picks), and the shortest path-length
    candidate not below the displacement's answer (0.011 m of printing slack each way)."""
    rows = recording_rows("distance_bound", seed=0)
    t = attack_table(rows, iface=IFACE, families="keyed", attacks=["keyed_distance_bound"])
    metres = lambda s: float(s.rstrip("m"))  # noqa: E731
    moved = lambda s: sum(float(x) for x in re.findall(r"move \w+ ([0-9.]+)m", s))  # noqa: E731
    by_video: dict = {}
    for r in rows:
        kind = {"Trajectory Description": "traj"}.get(r["Task"]) or (
            r["Task"] == D and ("disp" if "displacement" in r["Question"] else "path"))
        if kind:
            by_video.setdefault(r["Video"], {})[kind] = r
    hits = 0.0
    for rec in by_video.values():
        disp, path, traj = rec["disp"], rec["path"], rec["traj"]
        picks = set()
        for bound in (metres(path["Candidates"][path["Answer"]]), moved(traj["Candidates"][traj["Answer"]])):
            ok = {k: metres(v) for k, v in disp["Candidates"].items() if metres(v) <= bound * 1.001 + 0.011}
            if ok:
                picks.add(max(ok, key=ok.get))
        hits += (disp["Answer"] in picks) / max(len(picks), 1)
        floor = metres(disp["Candidates"][disp["Answer"]])
        ok = {k: metres(v) for k, v in path["Candidates"].items() if metres(v) >= floor * 0.999 - 0.011}
        hits += bool(ok) and min(ok, key=ok.get) == path["Answer"]
    cell = _cell(t, "keyed_distance_bound", D)
    assert cell["hits"] == pytest.approx(hits) and cell["significant"]
    assert hits > 0.6 * 2 * N_RECORDINGS


@pytest.mark.parametrize("plant", ["fewest_significant", "last_digit"])
def test_format_tie_sets_pick_the_whole_tie(plant):
    """A tie set is the pick: fmt_last_digit's best digit is the planted 7 and the table keeps it with a
    Bonferroni factor over the digits seen; ties are counted as tied rows."""
    rows = recording_rows(plant, seed=0)
    t = attack_table(rows, iface=IFACE, families="format", attacks=[PLANTED[plant][1]])
    hit = _cell(t, PLANTED[plant][1], S)
    speed = [r for r in rows if r["Task"] == S]
    if plant == "last_digit":
        assert hit["direction"] == "digit 7"
        tied = sum(sum(re.sub(r"[^0-9]", "", v)[-1] == "7" for v in r["Candidates"].values()) > 1 for r in speed)
    else:
        assert hit["direction"] == "max"  # the fewest significant digits (the score is their negative)
        tied = 0
        for r in speed:
            n = [_significant_digits(v) for v in r["Candidates"].values()]
            tied += n.count(min(n)) > 1
    assert hit["tied_rows"] == tied


@pytest.mark.slow  # over 3 s: make test runs it, make test-fast leaves it out
def test_recording_clean_control_has_no_false_alarm():
    t = attack_table(recording_rows(None, seed=0), iface=IFACE, families="all", learned=FAST_LEARNED)
    assert set(t["family"]) == set(FAMILIES) - {"metadata", "keyed"}  # no camera but camera 1: metadata has nothing
    assert not t["significant"].any(), t[t["significant"]][["attack", "task", "source", "accuracy", "p_holm"]]
    assert 0.15 < t["accuracy"].mean() < 0.25


def test_new_families_at_chance_on_the_clean_control():
    t = attack_table(recording_rows(None, seed=1), iface=IFACE, families=NEW_FAMILIES)
    assert {a for a in t["attack"]} >= {n for n, a in ATTACKS.items() if a.family == "relation"}
    assert not t["significant"].any(), t[t["significant"]][["attack", "task", "source", "accuracy", "p_holm"]]


def test_learned_population_finds_the_implied_rate_plant():
    """The question plant of the first synthetic release: the answer implies ~0.3 m/s over its window,
    the distractors were drawn for another window length; the population attacker reads each
    candidate's implied rate against the training rows' answers."""
    from tests.attack_release import release_rows

    rows = [r for r in release_rows("question", seed=1) if r["Task"] == "Displacement & Path Length"]
    t = attack_table(rows, iface=IFACE, families="learned_question", attacks=["learned_population"],
                     learned=FAST_LEARNED)
    hit = _cell(t, "learned_population", "Displacement & Path Length")
    assert hit["significant"] and hit["accuracy"] > 0.4, hit


def test_pose_rows_of_a_segment_share_one_track():
    """The plant's pose questions: each segment has POSE_ROWS questions and the answer of the plant lies
    on the line through the premises (checked here from the printed numbers)."""
    from resti_lib import values as V

    rows = [r for r in recording_rows("pose_track", seed=0) if r["Task"] == "Pose Estimation"]
    assert len(rows) == POSE_RECORDINGS * POSE_ROWS
    by_video = {}
    for r in rows:
        by_video.setdefault(r["Video"], []).append(r)
    worst = 0.0
    for group in by_video.values():
        pts = [(float(m), np.array(V.parse(p).t)) for r in group
               for m, p in re.findall(r"t=([\d.]+) s in the Waymo world coordinate frame: (\{[^}]*\})", r["Question"])]
        times = np.array([t for t, _ in pts])
        line = np.polyfit(times, np.array([p for _, p in pts]), 1)  # least squares through the premises
        for r in group:
            want = line[0] * r["time_end"] + line[1]
            worst = max(worst, float(np.linalg.norm(np.array(V.parse(r["Answer Detail"]).t) - want)))
    assert worst < 0.1  # printed at 0.01 m


# ------------------------------------------------------------------------------------ large effects

@pytest.mark.parametrize("n", [20, 27, 40, 60])
def test_large_effect_is_the_exact_interval_above_chance(n):
    """Second method: the lower end of the two-sided 99% exact interval of k/n lies above 1/5 exactly when
    a one-sided exact test at 0.5% rejects 1/5, i.e. P[Binomial(n, 1/5) >= k] < 0.005."""
    k = np.arange(n + 1)
    got = large_effects(k, np.full(n + 1, n), np.ones(n + 1))
    want = (binom.sf(k - 1, n, 0.2) < 0.005) & (k / n >= LARGE_EFFECT_AT) & (n >= LARGE_EFFECT_MIN_ROWS)
    assert np.array_equal(got, want)
    # an attack of five comparisons needs its interval at 99.8%: P[X >= k] < 0.001
    got5 = large_effects(k, np.full(n + 1, n), np.full(n + 1, 5))
    assert np.array_equal(got5, (binom.sf(k - 1, n, 0.2) < 0.001) & (k / n >= LARGE_EFFECT_AT))
    # read from the table's p-values (times the comparisons), the flag is the same for independent rows
    sf = binom.sf(k - 1, n, 0.2)
    assert np.array_equal(large_effects(k, np.full(n + 1, n), np.ones(n + 1), p_values=sf), want)
    assert np.array_equal(large_effects(k, np.full(n + 1, n), np.full(n + 1, 5), p_values=np.minimum(1, 5 * sf)), got5)


def test_large_effect_needs_rows_and_size():
    # 14 of 27 (the min pick after a widening of the Dimensional distractors): P[X >= 14] = 2.5e-4
    assert large_effects([14], [27], [1])[0]
    assert not large_effects([9], [19], [1])[0]  # 47%, but under 20 rows
    assert not large_effects([60], [200], [1])[0]  # significant, but 30% is no large effect


def _table_row(task, source, attack, acc, n, p, sig, large):
    return {"attack": attack, "family": ATTACKS[attack].family, "task": task, "source": source, "n_rows": n,
            "coverage": 1.0, "picked": n, "hits": acc * n, "accuracy": acc, "chance": 0.2, "p_value": p,
            "p_holm": min(1.0, p * 700), "significant": sig, "min_detectable": 0.5, "underpowered": True,
            "tied_rows": 0, "direction": "", "large_effect": large}


def test_headline_names_large_effects_after_significant_cells():
    table = pd.DataFrame([
        _table_row("Dimensional Measurement", "ScanNet", "min", 14 / 27, 27, 2.5e-4, False, True),
        _table_row("Dimensional Measurement", "ScanNet", "max", 0.3, 27, 0.1, False, False),
        _table_row("Dimensional Measurement", "Waymo", "min", 0.25, 26, 0.3, False, False),
        _table_row("Pose Estimation", "Waymo", "rel_pose_track", 0.99, 96, 1e-60, True, True),
    ])
    h = headline(table)
    assert list(zip(h["task"], h["source"])) == [("Pose Estimation", "Waymo"), ("Dimensional Measurement", "ScanNet"),
                                                 ("Dimensional Measurement", "Waymo")]
    assert list(h["large_effect"]) == [True, True, False] and list(h["large_effects"]) == [1, 1, 0]
    assert h.loc[1, "large_effect_attacks"] == "min (0.52, 14/27)" and not h.loc[1, "significant"]


def test_table_flags_large_effects_of_a_small_cell():
    """A 25-row cell whose answer is always the smallest candidate, in a release large enough that the
    min pick is still significant: flagged a large effect; the chance cells are not."""
    from tests.helpers import row

    rng = np.random.default_rng(4)
    rows = []
    for i in range(25):
        vals = sorted(rng.uniform(1, 9, 5))
        cands = {k: f"{v:.2f}m" for k, v in zip(LETTERS, rng.permutation(vals))}
        ans = min(cands, key=lambda k: float(cands[k][:-1]))
        rows.append(row(rid=i, video=f"scene{i:04d}_00.mp4", cands=cands, answer=ans))
    t = attack_table(rows, iface=IFACE, attacks=["min", "max", "median"]).set_index(["attack", "source"])
    assert t.loc[("min", "ScanNet"), "large_effect"] and t.loc[("min", "ScanNet"), "accuracy"] == 1.0
    assert not t.loc[("max", "ScanNet"), "large_effect"] and not t.loc[("median", "ScanNet"), "large_effect"]


# ------------------------------------------------------------------------------------ ReSTI v5

@pytest.fixture(scope="module")
def v5_rows(resti_v5_dir):
    return [json.loads(line) for line in (resti_v5_dir / "resti.jsonl").read_text(encoding="utf-8").splitlines()]


@pytest.mark.shared
def test_v5_converse_relations_are_mirrored(v5_rows):
    """Counted by a second method (the two objects read by a pattern of the question): in Omni6DPose
    Spatial Relation, 8 rows have their converse question in the same video and time, and all 8 answers
    mirror it; keyed_converse picks exactly those rows and hits all of them."""
    rel = [r for r in v5_rows if r["Task"] == "Spatial Relation" and r["Source"] == "Omni6DPose"]
    pat = re.compile(r"relative to the (.+?), is the (.+?) to the left")
    mirror = {"Left": "Right", "Right": "Left", "Closer": "Farther", "Farther": "Closer"}
    pairs = mirrored = 0
    for r in rel:
        a, b = pat.search(r["Question"]).groups()
        for o in rel:
            m = pat.search(o["Question"])
            if o is not r and o["Video"] == r["Video"] and o["time_start"] == r["time_start"] and m.groups() == (b, a):
                pairs += 1
                mirrored += mirror.get(o["Answer Detail"]) == r["Answer Detail"]
    assert pairs == mirrored == 8
    t = attack_table(v5_rows, iface=IFACE, families="keyed", attacks=["keyed_converse"])
    cell = _cell(t, "keyed_converse", "Spatial Relation")
    assert cell["picked"] == pairs and cell["hits"] == mirrored and cell["significant"]


@pytest.mark.shared
def test_v5_pose_track_and_travel_direction_in_waymo_pose(v5_rows):
    """Waymo Pose rows of one camera video print each other's poses as premises: a pose interpolated
    between the known poses of the video (or carried on from the two nearest) is the answer where
    two or more are known; and a vehicle's camera travels along its heading. Counted here by a second
    method: the rows whose video has another pose row (at least two known poses besides the answer)."""
    pose = [r for r in v5_rows if r["Task"] == "Pose Estimation" and r["Source"] == "Waymo"]
    per_video = Counter(r["Video"] for r in pose)
    with_sibling = sum(per_video[r["Video"]] > 1 for r in pose)
    t = attack_table(v5_rows, iface=IFACE, families=("relation", "question"),
                     attacks=["rel_pose_track", "travel_direction"])
    track = _cell(t, "rel_pose_track", "Pose Estimation").copy()
    waymo = t[(t["attack"] == "rel_pose_track") & (t["source"] == "Waymo")].iloc[0]
    assert waymo["picked"] == with_sibling and waymo["accuracy"] > 0.9 and waymo["significant"]
    assert track["family"] == "relation"
    travel = t[(t["attack"] == "travel_direction") & (t["source"] == "Waymo")].iloc[0]
    assert travel["significant"] and travel["accuracy"] > 0.5


@pytest.mark.shared
@pytest.mark.slow
def test_v5_camera_sets_not_shared_across_recordings_and_the_learned_attacker_at_chance(resti_v5_dir, tmp_path):
    """The outside review's learned attacker got 42 of 75 on re-optioned v5 Omni6DPose Speed &
    Acceleration (seed 0). Its source: camera rows of different recordings with the same window and the
    same printed answer shared one candidate set, so a learned reader trained on one recording
    recognised the set, and its answer, in another (a strong options-only attacker hit 0.82 of those
    rows and chance on the others). Cameras of two recordings are not one subject: no set is shared
    across them now, and the strong attacker is at chance on the cell before any adversarial filtering;
    the same rows with the shared sets put back are found (the test can fail)."""
    from resti_lib.release.reoption import reoption_release

    res = reoption_release(resti_v5_dir, tmp_path / "reopt", seed=0, options={"adversarial": {"rounds": 0}})
    rows = [json.loads(line) for line in (res.out_dir / "resti.jsonl").read_text(encoding="utf-8").splitlines()]
    speed = [r for r in rows if r["Task"] == "Speed & Acceleration"]
    video = {r["ReSTI ID"]: r["Video"] for r in rows}
    ev = res.evidence.set_index("rid")["shared_with"].dropna()
    omni = {r["ReSTI ID"] for r in speed if r["Source"] == "Omni6DPose"}  # every one asks the camera
    assert all(video[rid] == video[base] for rid, base in ev.items() if rid in omni)  # within a recording only
    strong = {"max_iter": 200, "max_leaf_nodes": 31, "min_samples_leaf": 8, "learning_rate": 0.08}

    def cell(rs):
        t = attack_table(rs, iface=IFACE, families=("learned_option",), attacks=["learned_blind"], learned=strong)
        return t[(t["source"] == "Omni6DPose") & (t["attack"] == "learned_blind")].iloc[0]

    assert not cell(speed)["significant"]
    # the sets shared again: camera rows with one question form, window and printed answer take the first one's
    first: dict = {}
    shared = []
    for r in speed:
        key = (r["Source"], re.sub(r"t=[\d.]+ s", "t", r["Question"]), round(r["time_end"] - r["time_start"], 3),
               r["Candidates"][r["Answer"]])
        c = first.setdefault(key, r["Candidates"]) if r["Source"] == "Omni6DPose" and "camera" in r["Question"] \
            else r["Candidates"]
        shared.append({**r, "Candidates": c, "Answer": next(k for k, v in c.items() if v == r["Candidates"][r["Answer"]])})
    assert sum(s["Candidates"] is not r["Candidates"] for s, r in zip(shared, speed)) >= 10
    again = cell(shared)
    assert again["significant"] and again["accuracy"] > 0.35


def _joint_box_rows(joint: bool, n: int = 300, seed: int = 5):
    """ScanNet boxes whose answers' centres lie near the line y = -x/2 (x, y each uniform-like over the
    population). Every candidate's x and y are drawn from the answers' own marginals; a joint plant keeps the
    distractors' x and y independent (each field as typical as the answer's, the pair off the line), the clean
    control puts them on the line too."""
    from resti_lib import values as V
    from tests.attack_release import _row

    rng = np.random.default_rng(seed)
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    rows = []
    for i in range(n):
        def box(on_line):
            x = float(rng.uniform(-1.0, 1.0))
            y = -0.5 * x + float(rng.normal(0, 0.03)) if on_line else float(-0.5 * rng.uniform(-1.0, 1.0))
            return V.format_box([x, y, 2.0], [0.8, 0.6, 0.7], R)
        cands = [box(True)] + [box(not joint) for _ in range(4)]
        order = rng.permutation(5)
        letters = {LETTERS[j]: cands[int(k)] for j, k in enumerate(order)}
        answer = LETTERS[int(np.flatnonzero(order == 0)[0])]
        q = (f"At {i}.0 seconds, what is the oriented 3D bounding box of the wooden table in the ScanNet OpenCV "
             "camera frame (+X right, +Y down, +Z forward)?")
        rows.append(_row("3D Video Grounding", "ScanNet", f"scene{i:04d}_00.mp4", q, letters, answer, i, float(i),
                         float(i)))
    return rows


@pytest.mark.parametrize("joint", [True, False])
def test_field_density_reads_fields_jointly(joint):
    """Each printed field of a distractor as typical as the answer's, the pair not: the joint share of answers
    among the nearest candidates finds the answer (the cell's best direction is a joint one); on the clean
    control (the distractors on the answers' line too) nothing is found."""
    rows = _joint_box_rows(joint)
    t = attack_table(rows, iface=IFACE, attacks=["field_density"])
    cell = _cell(t, "field_density", "3D Video Grounding")
    if joint:
        assert cell["significant"] and "joint" in str(cell["direction"]) and cell["accuracy"] >= 0.5, cell
    else:
        assert not cell["significant"] and cell["p_value"] > 0.01, cell
