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
