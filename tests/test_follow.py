"""Candidate sets that follow a related row of another task (resti_lib/options/follow.py): the links
found, and the follower's candidates computed by hand from the driver's."""

from __future__ import annotations

import numpy as np
import pytest

from resti_lib import values as V
from resti_lib.adjudicate import Rule
from resti_lib.errors import InputError
from resti_lib.options.follow import Link, find_box_links, find_link, follow_box, follow_strings
from resti_lib.options.observables import Observables
from resti_lib.options.spec import OptionSpec
from resti_lib.run.plan import main_config

TOL = {"relative_tol": 0.05, "angle_tol_deg": 3.0}


def spec(rid, task, quantity, detail, *, t0=0.0, t1=4.0, seq="seg1", noun="camera", kind=None):
    v = V.parse(detail)
    obs = Observables(task=task, source="Waymo", video=f"{seq}_camera_1", sequence=seq, camera="1", quantity=quantity,
                      time_start=t0, time_end=t1, window_s=None if t0 is None else t1 - t0, subject=noun,
                      subject_class=noun)
    kind = kind or ("angle" if isinstance(v, V.Scalar) and v.is_angle else v.kind)
    return OptionSpec(rid, task, "Waymo", kind, v, detail, obs, Rule())


def box(length, w, h, x=0.0):
    return V.format_box([x, 0.0, 10.0], [length, w, h], np.eye(3))


def test_speed_follows_a_distance_over_the_same_window():
    d = spec("d", "Displacement & Path Length", "path_length", "8.00m")
    f = spec("f", "Speed & Acceleration", "speed", "2.00m/s")
    link = find_link(f, [d], TOL)
    assert link == Link("f", "d", "per_window", None, False)
    # 8 m over 4 s is 2 m/s; the distractors 4, 12, 16, 2 m over 4 s are 1, 3, 4, 0.5 m/s
    out = follow_strings(link, f, d, ["4.00m", "8.00m", "12.00m", "16.00m", "2.00m"])
    assert sorted(out) == sorted(["1.00m/s", "2.00m/s", "3.00m/s", "4.00m/s", "0.50m/s"])


def test_no_link_without_the_relation():
    d = spec("d", "Displacement & Path Length", "path_length", "8.00m")
    assert find_link(spec("f", "Speed & Acceleration", "speed", "3.00m/s"), [d], TOL) is None  # 8/4 = 2, not 3
    assert find_link(spec("f", "Speed & Acceleration", "speed", "2.00m/s", t0=1.0, t1=5.0), [d], TOL) is None
    assert find_link(spec("f", "Speed & Acceleration", "speed", "2.00m/s", seq="seg2"), [d], TOL) is None
    same_task = spec("d2", "Speed & Acceleration", "path_length", "8.00m")
    assert find_link(spec("f", "Speed & Acceleration", "speed", "2.00m/s"), [same_task], TOL) is None


def test_a_box_follows_the_dimensions_asked_of_its_subject():
    g = spec("g", "3D Video Grounding", "box", box(4.5, 1.8, 1.5), noun="car")
    width = spec("w", "Dimensional Measurement", "width", "1.80m", noun="car")
    length = spec("l", "Dimensional Measurement", "length", "450cm", noun="car")
    links = find_box_links(g, [width, length], TOL)
    assert [(lk.driver, lk.edge) for lk in links] == [("l", 0), ("w", 1)]
    own = [box(4.5, 1.8, 1.5), box(4.4, 1.82, 1.5, 1.0), box(4.6, 1.79, 1.4, 2.0), box(4.5, 1.81, 1.6, 3.0),
           box(4.45, 1.8, 1.55, 4.0)]
    drivers = {"w": (width, ["1.80m", "2.10m", "1.50m", "2.40m", "1.20m"]),
               "l": (length, ["450cm", "400cm", "500cm", "420cm", "480cm"])}
    out = follow_box(links, g, drivers, own, {"d0": 3, "d1": 3, "d2": 3})
    got = sorted((V.parse(t).lwh[0], V.parse(t).lwh[1], V.parse(t).lwh[2], V.parse(t).center[0]) for t in out)
    # distractor j keeps its own centre and height; its length and width are the dimension rows'
    # distractor j (in metres): by hand
    assert got == sorted([(4.5, 1.8, 1.5, 0.0), (4.0, 2.1, 1.5, 1.0), (5.0, 1.5, 1.4, 2.0), (4.2, 2.4, 1.6, 3.0),
                          (4.8, 1.2, 1.55, 4.0)])
    # another noun, or a dimension no edge has: no link
    assert find_box_links(g, [spec("w", "Dimensional Measurement", "width", "1.80m", noun="truck")], TOL) == []
    assert find_box_links(g, [spec("w", "Dimensional Measurement", "width", "2.50m", noun="car")], TOL) == []


def test_a_heading_change_follows_the_turn_sum():
    d = spec("t", "Trajectory Description", "trajectory", "move forward 10.0m, then turn left 30°, then move forward 5.0m")
    f = spec("f", "Ego-Centric Orientation", "heading_change", "31.50°")
    link = find_link(f, [d], TOL)
    assert link.additive and link.relation == "turn_sum"
    cands = ["move forward 10.0m, then turn left 30°, then move forward 5.0m",
             "move forward 10.0m, then turn right 45°, then move forward 5.0m",
             "move forward 10.0m, then turn left 90°, then move forward 5.0m",
             "move forward 12.0m, then turn left 60°, then move forward 5.0m",
             "move forward 10.0m, then turn right 10°, then move forward 5.0m"]
    # the answer is 1.5 degrees past the turn sum; so is every image
    assert sorted(follow_strings(link, f, d, cands)) == sorted(["31.50°", "-43.50°", "91.50°", "61.50°", "-8.50°"])
    # two driver candidates with one turn sum give one image twice: no set
    cands[1] = "move forward 20.0m, then turn left 30°, then move forward 5.0m"
    assert follow_strings(link, f, d, cands) is None


def test_task_stages_run_after_the_tasks_they_follow(tmp_path):
    stages = {s["notebook"]: s for s in main_config()["stages"]}
    assert stages["06_speed"]["wave"] > stages["05_displacement"]["wave"] > stages["07_trajectory"]["wave"]
    from resti_lib.tasks import all_tasks

    assert stages["99_release_report"]["wave"] > max(stages[t.notebook]["wave"] for t in all_tasks())
    # a stage that reads every task's outputs, listed beside a task wave, is refused by name
    import yaml

    from resti_lib import paths

    cfg = yaml.safe_load((paths.PARAMS / "default.yaml").read_text())
    cfg["stages"][0]["wave"] = 2
    f = tmp_path / "main.yaml"
    f.write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError, match="99_release_report runs in wave 2"):
        main_config(f)


def test_a_displacement_follows_the_path_length_it_cannot_exceed():
    """A displacement is at most the path over its window: it follows the path length asked beside it
    (its own task) or a trajectory description's total, whatever its ratio below the path; its
    candidates are the path candidates times the answer's ratio (6 m of 10 m: 0.6 of each)."""
    path = spec("p", "Displacement & Path Length", "path_length", "10.00m")
    disp = spec("f", "Displacement & Path Length", "displacement", "6.00m")
    link = find_link(disp, [path], TOL)
    assert link == Link("f", "p", "path_bound", None, False)
    out = follow_strings(link, disp, path, ["10.00m", "5.00m", "20.00m", "12.50m", "7.00m"])
    assert sorted(out) == sorted(["6.00m", "3.00m", "12.00m", "7.50m", "4.20m"])
    # every candidate lies within exactly the path candidate it was made from, as the answer does
    assert all(a / b == pytest.approx(0.6) for a, b in zip([3.0, 12.0, 7.5, 4.2], [5.0, 20.0, 12.5, 7.0]))
    traj = spec("t", "Trajectory Description", "trajectory", "move forward 8.0m, then turn left 30°, then move forward 2.0m")
    assert find_link(disp, [traj], TOL).relation == "path_bound"
    # longer than the path (past the 5% tolerance), another window or another recording: no link
    assert find_link(spec("f", "Displacement & Path Length", "displacement", "10.60m"), [path], TOL) is None
    assert find_link(spec("f", "Displacement & Path Length", "displacement", "10.40m"), [path], TOL) is not None
    assert find_link(spec("f", "Displacement & Path Length", "displacement", "6.00m", t0=1.0, t1=5.0), [path],
                     TOL) is None
    assert find_link(spec("f", "Displacement & Path Length", "displacement", "6.00m", seq="seg2"), [path], TOL) is None


_MOVE = r"move forward ([0-9.]+)m"
_TURN = r"turn (left|right) ([0-9]+)°"


def _turns(phrase: str) -> tuple:
    import re

    return tuple(int(n) * (1 if side == "left" else -1) for side, n in re.findall(_TURN, phrase))


def _total(phrase: str) -> float:
    import re

    return sum(float(x) for x in re.findall(_MOVE, phrase))


def test_the_camera_videos_of_one_drive_get_translates_of_one_trajectory_set(main_run):
    """The camera videos of one Waymo segment describe one drive, each from its mount: path lengths a
    few centimetres apart, the same turns. Their candidate sets are translates of one set (each
    candidate moved by the difference of the answers), so the turns every set shares with the
    segment's heading-change rows single out nothing. Read by hand from the release with regexes."""
    import itertools
    import json
    from collections import defaultdict

    rows = [json.loads(x) for x in (main_run.out / "release" / "resti.jsonl").read_text().splitlines() if x.strip()]
    drives = defaultdict(list)
    for r in rows:
        if r["Task"] == "Trajectory Description" and r["Source"] == "Waymo" and _turns(r["Answer Detail"]):
            drives[(r["Video"].split("_camera")[0], r["time_start"], round(r["time_end"], 3))].append(r)
    pairs = moved = 0
    for group in drives.values():
        for a, b in itertools.combinations(group, 2):
            d = _total(b["Answer Detail"]) - _total(a["Answer Detail"])
            if _turns(a["Answer Detail"]) != _turns(b["Answer Detail"]) or abs(d) >= 1.0:
                continue
            pairs += 1
            moved += d != 0
            assert sorted(map(_turns, a["Candidates"].values())) == sorted(map(_turns, b["Candidates"].values()))
            n_moves = a["Answer Detail"].count("move forward")
            ta = np.sort([_total(c) for c in a["Candidates"].values()])
            tb = np.sort([_total(c) for c in b["Candidates"].values()])
            assert np.allclose(ta + d, tb, atol=0.15 * n_moves + 1e-9), (a["Video"], b["Video"], ta, tb)
    assert pairs >= 3 and moved >= 1, (pairs, moved)
    # a heading change over the drive's window: each candidate is the turn sum of one trajectory
    # candidate of each camera's set (within the follow's residual), so the relation ties all five
    checked = 0
    for r in rows:
        if r["Task"] != "Ego-Centric Orientation" or r["Source"] != "Waymo":
            continue
        drive = drives.get((r["Video"].split("_camera")[0], r["time_start"], round(r["time_end"], 3)))
        if not drive:
            continue
        angles = [float(c.rstrip("°")) for c in r["Candidates"].values()]
        for t in drive:
            sums = [sum(_turns(c)) for c in t["Candidates"].values()]
            nearest = [min(sums, key=lambda x: abs(x - a)) for a in angles]
            assert sorted(nearest) == sorted(sums) and all(abs(a - n) < 1.0 for a, n in zip(angles, nearest)), \
                (r["Video"], angles, t["Video"], sums)
            checked += 1
    assert checked >= 6, checked


def test_the_attack_suite_reads_each_drives_translated_sets_as_one_draw(main_run):
    """The camera videos' trajectory sets that are translates of one set (found by hand above: the same
    turns, totals moved by the difference of the answers) are one draw for the attack suite's exact test:
    ``Batch.coupled``, which reads only the strings, puts each such pair in one cluster, and the slots it
    gives map the sorted totals of one onto the other."""
    import itertools
    import json
    from collections import defaultdict

    from resti_lib.options.attacks.batch import make_batch, parse_rows
    from resti_lib.tasks import interface

    rows = [json.loads(x) for x in (main_run.out / "release" / "resti.jsonl").read_text().splitlines() if x.strip()]
    batch, used = make_batch(parse_rows(rows), rows, iface=interface())
    cluster, slots = batch.coupled()
    at = {u: i for i, u in enumerate(used)}
    drives = defaultdict(list)
    for n, r in enumerate(rows):
        if r["Task"] == "Trajectory Description" and r["Source"] == "Waymo" and _turns(r["Answer Detail"]) \
                and n in at:
            drives[(r["Video"].split("_camera")[0], r["time_start"], round(r["time_end"], 3))].append(n)
    pairs = 0
    for group in drives.values():
        for a, b in itertools.combinations(group, 2):
            ra, rb = rows[a], rows[b]
            d = _total(rb["Answer Detail"]) - _total(ra["Answer Detail"])
            if _turns(ra["Answer Detail"]) != _turns(rb["Answer Detail"]) or abs(d) >= 1.0:
                continue
            pairs += 1
            i, j = at[a], at[b]
            assert cluster[i] is not None and cluster[i] == cluster[j], (ra["Video"], rb["Video"])
            ta = [_total(ra["Candidates"][k]) for k in slots[i]]
            tb = [_total(rb["Candidates"][k]) for k in slots[j]]
            assert np.allclose(np.add(ta, d), tb, atol=0.15 * ra["Answer Detail"].count("move forward") + 1e-9)
    assert pairs >= 3, pairs
