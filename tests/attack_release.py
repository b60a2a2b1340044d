"""Synthetic releases for the attack suite's tests: a clean control and one planted tell per family.

The clean control draws, for every row, the answer and its four distractors independently from one
distribution *given the question's observables* (window, premise pose, camera) and assigns the letters
at random: nothing blind can tell the answer from a distractor, so every attack is at chance. Each
plant changes exactly one channel of the clean release, which one family of the suite reads.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from resti_lib import LETTERS
from resti_lib import values as V

CELL_ROWS = 120        # rows per task/source cell
ROWS_PER_VIDEO = 4
RELATIONS = ("Front", "Front-Left", "Front-Right", "Left", "Right")
CAMERA_LABEL = {1: "Front", 2: "Front-Left", 3: "Front-Right", 4: "Left", 5: "Right"}
PLANTS = ("option", "format", "typicality", "question", "premise", "cross_row", "metadata")


def _row(task, source, video, question, cands, answer, rid, t0, t1):
    return {"Video": video, "Source": source, "Task": task, "QType": "Single Choice", "Question": question,
            "Prompt": "", "time_start": t0, "time_end": t1, "Candidates": cands, "Answer": answer,
            "Answer Detail": cands[answer], "ID": rid, "ReSTI ID": f"test:{task}:{rid}",
            "scene": {"ScanNet": "indoor", "Waymo": "outdoor", "Omni6DPose": "desktop"}[source]}


def _letters(strings: list, answer_index: int, rng) -> tuple[dict, str]:
    """Candidates in random letter order; returns the candidates and the answer letter."""
    order = rng.permutation(5)
    cands = {LETTERS[j]: strings[order[j]] for j in range(5)}
    return cands, LETTERS[int(np.flatnonzero(order == answer_index)[0])]


def _displacement(rng, plant) -> list:
    rows = []
    for i in range(CELL_ROWS):
        d = float(rng.uniform(2, 60))
        t0 = float(rng.integers(0, 30))
        speeds = np.exp(rng.normal(np.log(0.3), 0.5, 5))
        vals = speeds * d
        a = int(rng.integers(5))
        if plant == "option":
            a = int(np.argmax(vals))
        elif plant == "question":  # distractors ignore the window: values of another window length
            vals = np.concatenate([vals[:1], np.exp(rng.normal(np.log(0.3 * 31), 1.0, 4))])
            a = 0
        strings = [V.format_scalar(float(x), "m") for x in vals]
        if plant == "format":
            strings[a] = V.format_scalar(float(vals[a]), "m", 3)
        q = (f"What is the displacement (straight-line distance) of the camera between t={V.format_seconds(t0)} s "
             f"and t={V.format_seconds(t0 + d)} s? (unit: m)")
        cands, ans = _letters(strings, a, rng)
        rows.append(_row("Displacement & Path Length", "ScanNet", f"scene{i // ROWS_PER_VIDEO:04d}_00.mp4", q, cands,
                         ans, i, t0, t0 + d))
    return rows


def _yaw_pose(t, yaw_deg) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = t
    return T


def _pose(rng, plant) -> list:
    rows = []
    n_videos = CELL_ROWS // ROWS_PER_VIDEO
    for v in range(n_videos):
        video = f"{1000 + v}{v:04d}_100_000_120_000_camera_1.mp4"
        previous_answer = None
        for j in range(ROWS_PER_VIDEO):
            i = v * ROWS_PER_VIDEO + j
            P = _yaw_pose([rng.normal(0, 300), rng.normal(0, 300), rng.normal(0, 5)], rng.uniform(-180, 180))
            premise = V.format_pose(P, 2, compact=True)
            if plant == "cross_row" and previous_answer is not None:
                premise = previous_answer  # the previous row's answer is this row's premise, verbatim
                P = V.parse(premise).matrix
            dist = rng.uniform(5, 50, 5)
            if plant == "premise":
                dist[0] = rng.uniform(0.5, 4)
            opts = []
            for k in range(5):
                ang = rng.uniform(0, 2 * np.pi)
                M = _yaw_pose([dist[k] * np.cos(ang), dist[k] * np.sin(ang), rng.normal(0, 0.2)], rng.normal(0, 20))
                opts.append(V.format_pose(P @ M, 2, compact=True))
            a = 0 if plant == "premise" else int(rng.integers(5))
            if len(set(opts)) < 5:
                opts = [o for o in dict.fromkeys(opts)] + [V.format_pose(P @ _yaw_pose([99 + k, 0, 0], 0), 2,
                                                                             compact=True) for k in range(5)]
                opts = opts[:5]
            t_p, t_a = float(rng.integers(0, 8)), float(rng.integers(10, 20))
            q = (f"Given the camera pose at t={V.format_seconds(t_p)} s in the Waymo world coordinate frame: {premise}, "
                 f"what is the camera pose in the same coordinate frame at t={V.format_seconds(t_a)} s?")
            cands, ans = _letters(opts, a, rng)
            previous_answer = cands[ans]
            rows.append(_row("Pose Estimation", "Waymo", video, q, cands, ans, 1000 + i, t_a, t_a))
    return rows


def _box_strings(rng, n, *, correlated=True, pool=None) -> list:
    out = []
    for _k in range(n):
        c = rng.normal([0, 0.5, 8], [2, 0.3, 2])
        if correlated or pool is None:
            s = np.exp(rng.normal(0, 0.3))
            lwh = s * np.array([4.5, 1.9, 1.5]) * np.exp(rng.normal(0, 0.03, 3))
        else:  # each edge from another box: the marginals of real boxes, not their correlation
            lwh = np.array([pool[rng.integers(len(pool))][d] for d in range(3)])
        R = Rotation.from_euler("y", rng.uniform(-180, 180), degrees=True).as_matrix()
        out.append((V.format_box(c, lwh, R), lwh))
    return out


def _grounding(rng, plant) -> list:
    rows = []
    pool = [b[1] for b in _box_strings(rng, 400)]
    for i in range(CELL_ROWS):
        t = float(rng.uniform(0, 19))
        boxes = _box_strings(rng, 1) + _box_strings(rng, 4, correlated=plant != "typicality", pool=pool)
        strings = [b[0] for b in boxes]
        a = 0 if plant == "typicality" else int(rng.integers(5))
        if plant != "typicality":
            strings = [b[0] for b in _box_strings(rng, 5)]
        q = (f"At {V.format_seconds(t)} seconds, what is the oriented 3D bounding box of a dark sedan in an OpenCV "
             "camera frame (+X right, +Y down, +Z forward)?")
        cands, ans = _letters(strings, a, rng)
        rows.append(_row("3D Video Grounding", "Waymo", f"{2000 + i // ROWS_PER_VIDEO}_0_000_20_000_camera_1.mp4",
                         q, cands, ans, 2000 + i, t, t))
    return rows


def _relation(rng, plant) -> list:
    rows = []
    for i in range(CELL_ROWS):
        cam = int(rng.integers(1, 6))
        label = CAMERA_LABEL[cam] if plant == "metadata" else RELATIONS[int(rng.integers(5))]
        strings = list(RELATIONS)
        cands, ans = _letters(strings, strings.index(label), rng)
        q = "What is the orientation of the camera mounted on the moving car relative to the car's forward direction?"
        rows.append(_row("Spatial Relation", "Waymo", f"{3000 + i}_0_000_20_000_camera_{cam}.mp4", q, cands, ans,
                         3000 + i, 0.0, 19.8))
    return rows


def release_rows(plant: str | None = None, seed: int = 0) -> list[dict]:
    """A release of four task/source cells (Displacement ScanNet, Pose Waymo, Grounding Waymo, Spatial
    Relation Waymo), clean, or with one tell planted (see :data:`PLANTS`)."""
    if plant not in (None, *PLANTS):
        raise ValueError(plant)
    rng = np.random.default_rng(seed)
    return _displacement(rng, plant) + _pose(rng, plant) + _grounding(rng, plant) + _relation(rng, plant)


# ------------------------------------------------------------------------------------ recordings
# A second synthetic release for the channels that need several rows of one recording (family
# ``relation``), the direction of travel, formatting tie sets, release-wide priors and the learned
# population attacker. Every recording asks the same questions; in the clean control every answer and
# its four distractors are independent draws from one distribution given the question, so no row
# reveals another. Each plant ties one channel to the answer.

N_RECORDINGS = 60
POSE_RECORDINGS = 40
POSE_ROWS = 4
NOUNS = ("chair", "table", "sofa", "cabinet", "lamp")
SPATIAL = ("Left", "Right", "Closer", "Farther", "Directly above")
MIRRORED = {"Left": "Right", "Right": "Left", "Closer": "Farther", "Farther": "Closer"}
RECORDING_PLANTS = ("rate_window", "path_length", "distance_bound", "turn_sum", "box_edge", "pose_track", "converse",
                    "travel_direction", "fewest_significant", "shortest", "last_digit", "string_rate", "field_rate",
                    "field_density", "nearest_set")
STRING_POOL = tuple(f"{0.50 + 0.05 * i:.2f}m" for i in range(20))


def _distinct(draw, n: int = 5, first=None) -> list:
    """``n`` distinct strings: ``first`` (when given) and draws of ``draw()``."""
    out = [first] if first is not None else []
    while len(out) < n:
        s = draw()
        if s not in out:
            out.append(s)
    return out


def _window_q(kind: str, t0: float, t1: float) -> str:
    a, b = V.format_seconds(t0), V.format_seconds(t1)
    return {
        "speed": f"What is the magnitude of the camera's average velocity between t={a} s and t={b} s, computed as "
                 "straight-line endpoint displacement divided by elapsed time? (unit: m/s)",
        "displacement": f"What is the displacement (straight-line distance) of the camera between t={a} s and t={b} s? "
                        "(unit: m)",
        "path_length": f"What is the trajectory length (total distance traveled) of the camera between t={a} s and "
                       f"t={b} s? (unit: m)",
        "trajectory": f"Which option best describes the camera's movement trajectory between t={a} s and t={b} s? "
                      "Distances are path lengths along the trajectory and turns are net heading changes.",
        "heading": f"Between source pose timestamps {a} and {b} seconds, what is the signed horizontal heading change "
                   "of the camera? Positive angles are counterclockwise about +up when viewed from above.",
    }[kind]


def _traj(rng, w: float) -> tuple[str, float, float]:
    """A trajectory phrase with one turn, its total distance and its signed turn."""
    a, b = np.exp(rng.normal(np.log(0.25), 0.4, 2)) * w
    turn = float(rng.choice([-1, 1]) * rng.integers(20, 121))
    return V.format_trajectory([("move", a), ("turn", turn), ("move", b)]), float(round(a, 1) + round(b, 1)), turn


def _scannet_recording(rng, r: int, plant) -> list:
    """Speed, displacement, path length, trajectory, heading change, a dimension and a box of one scene, all
    over one window (the box at one instant)."""
    video, rows = f"scene{r:04d}_00.mp4", []
    t0 = float(rng.integers(0, 30))
    w = float(rng.integers(20, 200)) / 10
    t1 = t0 + w
    rid = 10000 + 20 * r

    def add(task, question, strings, answer_index, t_start=t0, t_end=t1):
        cands, ans = _letters(strings, answer_index, rng)
        rows.append(_row(task, "ScanNet", video, question, cands, ans, rid + len(rows), t_start, t_end))

    speed = lambda: float(np.exp(rng.normal(np.log(0.3), 0.5)))
    v = speed()
    # speed: formatting plants print the answer differently, with the same value distribution
    if plant == "fewest_significant":
        vs = _distinct(lambda: V.format_scalar(speed(), "m/s"), first=V.format_scalar(round(v, 1), "m/s"))
    elif plant == "shortest":
        vs = _distinct(lambda: V.format_scalar(speed(), "m/s"), first=V.format_scalar(round(v, 1), "m/s", 1))
    elif plant == "last_digit":
        vs = _distinct(lambda: V.format_scalar(speed(), "m/s"), first=f"{np.floor(v * 10) / 10 + 0.07:.2f}m/s")
    elif plant == "nearest_set":  # slow scenes: the answer is the smallest candidate; fast ones: the largest
        scale, vs = (0.1 if r % 2 else 1.0), []
        while len(set(vs)) < 5:
            vals = sorted(np.exp(rng.normal(np.log(scale), 0.3, 5)))
            vs = [V.format_scalar(x, "m/s", 3) for x in (vals if r % 2 else vals[::-1])]
    else:
        vs = _distinct(lambda: V.format_scalar(speed(), "m/s"), first=V.format_scalar(v, "m/s"))
    add("Speed & Acceleration", _window_q("speed", t0, t1), vs, 0)
    v_printed = V.parse(vs[0]).si
    # displacement over the same window: its answer is the speed times the window in the plant
    d = v_printed * w if plant == "rate_window" else speed() * w
    add("Displacement & Path Length", _window_q("displacement", t0, t1),
        _distinct(lambda: V.format_scalar(speed() * w, "m"), first=V.format_scalar(d, "m")), 0)
    # trajectory and path length over the same window
    traj, total, turn = _traj(rng, w)
    add("Trajectory Description", _window_q("trajectory", t0, t1),
        _distinct(lambda: _traj(rng, w)[0], first=traj), 0)
    other_total = _traj(rng, w)[1]
    if plant == "distance_bound":  # a nearly straight drive: the displacement is 90-100% of the path length
        other_total = V.parse(rows[1]["Answer Detail"]).si / float(rng.uniform(0.9, 1.0))
    add("Displacement & Path Length", _window_q("path_length", t0, t1),
        _distinct(lambda: V.format_scalar(_traj(rng, w)[1], "m"),
                  first=V.format_scalar(total if plant == "path_length" else other_total, "m")), 0)
    heading = turn if plant == "turn_sum" else float(rng.choice([-1, 1]) * rng.integers(20, 121))
    add("Ego-Centric Orientation", _window_q("heading", t0, t1),
        _distinct(lambda: V.format_angle(float(rng.choice([-1, 1]) * rng.integers(20, 121))),
                  first=V.format_angle(heading)), 0)
    # a box and a dimension of one object
    noun = NOUNS[r % len(NOUNS)]
    lwh = lambda: np.exp(rng.normal(np.log([1.2, 0.8, 0.9]), 0.25))

    def box(edges, spread=1.0):
        R = Rotation.from_euler("y", rng.uniform(-180, 180), degrees=True).as_matrix()
        return V.format_box(rng.normal([0, 0.3, 3], np.array([1, 0.2, 0.5]) * spread), edges, R)

    edges = lwh()
    if plant == "field_rate":  # the answer's height prints one of two common values
        edges[2] = float(rng.choice([0.75, 0.9]))
    t_box = round(t0 + w / 2, 1)
    add("3D Video Grounding", f"At {V.format_seconds(t_box)} seconds, what is the oriented 3D bounding box of the "
        f"{noun} in an OpenCV camera frame (+X right, +Y down, +Z forward)?",
        # field_density: the answer's centre is always near the middle of where the distractors' centres fall
        _distinct(lambda: box(lwh()), first=box(edges, 0.05 if plant == "field_density" else 1.0)), 0,
        t_box, t_box)
    length = float(np.max(V.parse(rows[-1]["Answer Detail"]).lwh)) if plant == "box_edge" else float(np.max(lwh()))
    if plant == "string_rate":  # answers come from one half of a pool of strings, distractors from the other
        answers = [x for i, x in enumerate(STRING_POOL) if (i * 7) % 20 < 10]
        others = [x for x in STRING_POOL if x not in answers]
        dim = _distinct(lambda: others[int(rng.integers(len(others)))], first=answers[int(rng.integers(len(answers)))])
    else:
        dim = _distinct(lambda: V.format_scalar(float(np.max(lwh())), "m"), first=V.format_scalar(length, "m"))
    add("Dimensional Measurement", f"What is the length of the {noun}? Length, width and height are the box "
        "dimensions along its heading, across it, and vertically. (unit: m)", dim, 0, t0, t1)
    return rows


def _waymo_pose_recording(rng, r: int, plant) -> list:
    """Pose questions of one camera of one segment: premises printed on the vehicle's straight track; the
    answer is the pose at the target time (on the track in the plant ``pose_track``, displaced along the
    camera's forward axis in the plant ``travel_direction``, else anywhere at a travelled distance)."""
    video = f"{5000 + r}{r:04d}_100_000_120_000_camera_1.mp4"
    p0 = rng.normal(0, 300, 3) * [1, 1, 0]
    heading = rng.uniform(-180, 180)
    u = np.array([np.cos(np.radians(heading)), np.sin(np.radians(heading)), 0.0]) * rng.uniform(3, 12)
    yaw = rng.uniform(-180, 180)  # the camera's yaw, unrelated to the track's direction
    times = rng.permutation(np.arange(0, 200))[:2 * POSE_ROWS] / 10
    rows = []
    for j in range(POSE_ROWS):
        tp, ta = float(times[2 * j]), float(times[2 * j + 1])
        P = _yaw_pose(p0 + u * tp, yaw)
        premise = V.format_pose(P, 2, compact=True)

        def moved(direction=None, P=P, tp=tp, ta=ta):
            dist = abs(ta - tp) * rng.uniform(3, 12)
            ang = rng.uniform(0, 2 * np.pi)
            step = direction if direction is not None else np.array([np.cos(ang), np.sin(ang), 0.0])
            return V.format_pose(_yaw_pose(P[:3, 3] + dist * step, yaw + rng.normal(0, 5)), 2, compact=True)

        if plant == "pose_track":
            first = V.format_pose(_yaw_pose(p0 + u * ta, yaw + rng.normal(0, 5)), 2, compact=True)
        elif plant == "travel_direction":  # along one axis of the camera (its x), backwards for an earlier target
            first = moved(P[:3, :3] @ np.array([1.0, 0.0, 0.0]) * (1 if ta > tp else -1))
        else:
            first = moved()
        opts = _distinct(moved, first=first)
        q = (f"Given the camera pose at t={V.format_seconds(tp)} s in the Waymo world coordinate frame: {premise}, "
             f"what is the camera pose in the same coordinate frame at t={V.format_seconds(ta)} s?")
        cands, ans = _letters(opts, 0, rng)
        rows.append(_row("Pose Estimation", "Waymo", video, q, cands, ans, 20000 + POSE_ROWS * r + j, ta, ta))
    return rows


def _converse_recording(rng, r: int, plant) -> list:
    """Two spatial relations of one scene at one instant: B relative to A, then A relative to B."""
    video = f"{r:06d}.mp4"
    a, b = NOUNS[r % len(NOUNS)], NOUNS[(r + 2) % len(NOUNS)]
    if plant == "converse":
        first = list(MIRRORED)[int(rng.integers(4))]
        labels = [first, MIRRORED[first]]
    else:
        labels = [SPATIAL[int(rng.integers(5))] for _ in range(2)]
    rows = []
    for j, (x, y) in enumerate([(a, b), (b, a)]):
        q = (f"Viewed from the camera at t=0 s: relative to the {x}, is the {y} to the left, to the right, closer to "
             "the camera, farther from the camera, or directly above? Choose the single dominant relation.")
        cands, ans = _letters(list(SPATIAL), SPATIAL.index(labels[j]), rng)
        rows.append(_row("Spatial Relation", "Omni6DPose", video, q, cands, ans, 30000 + 2 * r + j, 0.0, 0.0))
    return rows


def recording_rows(plant: str | None = None, seed: int = 0) -> list[dict]:
    """A release of recordings that each ask several related questions (ScanNet scenes: speed, displacement,
    path length, trajectory, heading change, box and length over one window; Waymo segments: four pose
    questions; Omni6DPose scenes: a converse pair of spatial relations), clean, or with one channel planted
    (see :data:`RECORDING_PLANTS`)."""
    if plant not in (None, *RECORDING_PLANTS):
        raise ValueError(plant)
    rng = np.random.default_rng(seed)
    rows = []
    for r in range(N_RECORDINGS):
        rows += _scannet_recording(rng, r, plant)
    for r in range(POSE_RECORDINGS):
        rows += _waymo_pose_recording(rng, r, plant)
    for r in range(N_RECORDINGS):
        rows += _converse_recording(rng, r, plant)
    return rows


# ------------------------------------------------------------------------------------ echo
# A release whose distractors echo the answers: each scene's four distractors are drawn around other
# scenes' answers (a narrow kernel density of the other answers, as a distractor generator fitted on the
# answers draws them), so every answer recurs, slightly moved, among the other scenes' candidates. In
# the clean control the distractors are drawn from the answers' own distribution instead.

ECHO_SCENES = 250
ECHO_LOG_SD = 0.005   # log spread of a distractor around the answer it echoes (the answers' log spread: 0.5)


def echo_rows(echo: bool = True, seed: int = 0, n: int = ECHO_SCENES) -> list[dict]:
    """One average-speed question per ScanNet scene, its answer drawn from one log-normal; distractors
    drawn around the other scenes' answers (``echo``) or from that log-normal (clean). Printed to the
    millimetre per second, so a distractor rarely prints as the answer it echoes."""
    rng = np.random.default_rng(seed)
    answers = np.exp(rng.normal(np.log(0.3), 0.5, n))
    rows = []
    def draw(others: np.ndarray) -> str:
        x = others[rng.integers(len(others))] * np.exp(rng.normal(0, ECHO_LOG_SD)) if echo else \
            np.exp(rng.normal(np.log(0.3), 0.5))
        return V.format_scalar(float(x), "m/s", 3)

    for r in range(n):
        others = np.delete(answers, r)
        strings = _distinct(lambda others=others: draw(others), first=V.format_scalar(float(answers[r]), "m/s", 3))
        t0 = float(rng.integers(0, 30))
        cands, ans = _letters(strings, 0, rng)
        rows.append(_row("Speed & Acceleration", "ScanNet", f"scene{r:04d}_00.mp4", _window_q("speed", t0, t0 + 5),
                         cands, ans, 30000 + r, t0, t0 + 5))
    return rows
