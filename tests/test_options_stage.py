"""The option stage: exchangeable candidates given the question, separation, plausibility, formatting.

Every attack below is written here, independently of the attack suite: it knows the true
distribution the synthetic answers were drawn from (a stronger reader than any learned one), and
it is run against a naive construction too, so each test can fail.
"""

from __future__ import annotations

import json
import math
from collections import Counter

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import binomtest, chisquare, norm

from resti_lib import LETTERS
from resti_lib import values as V
from resti_lib.errors import InputError
from resti_lib.geometry.fields import rotation_preimage
from resti_lib.options.attacks import attack_table
from resti_lib.options.checks import ROW_CHECKS, parse_row
from resti_lib.options.spec import Interface, deep_merge
from resti_lib.options.stage import build_options
from resti_lib.options.structural import STRUCTURAL_REASONS, evaluation_subset, residual_ids, structural_leaks
from resti_lib.tasks import interface as _interface

IFACE = _interface()


def _row(i, task, source, question, detail, video=None, t0=0.0, t1=5.0, labels=None):
    cands = dict(zip(LETTERS, labels)) if labels else {L: detail for L in LETTERS}
    return {"Video": video or f"v{i}.mp4", "Source": source, "Task": task, "QType": "Single Choice",
            "Question": question, "Prompt": "", "time_start": t0, "time_end": t1, "Candidates": cands,
            "Answer": "A", "Answer Detail": detail, "ID": i, "scene": "outdoor", "ReSTI ID": f"r{i}",
            "Legacy Row Key": f"k{i}"}


def _displacement_rows(n=400, seed=0):
    """Camera displacements of a car: rate ~ lognormal(log 8, 0.4) m/s over windows of 0.5-15 s."""
    rng = np.random.default_rng(seed)
    rows, truth = [], []
    for i in range(n):
        w = float(np.round(rng.uniform(0.5, 15.0), 1))
        rate = float(np.exp(rng.normal(math.log(8.0), 0.4)))
        q = (f"What is the displacement (straight-line distance) of the camera between t=1 s and "
             f"t={1 + w:g} s? (unit: m)")
        rows.append(_row(i, "Displacement & Path Length", "Waymo", q, V.format_scalar(rate * w, "m"),
                         video=f"seg{i}_camera_1.mp4", t0=1.0, t1=1.0 + w))
        truth.append(w)
    return rows, truth


def _implied_rate_attack(rows, windows) -> float:
    """Pick the candidate whose implied rate is most probable under the true rate distribution."""
    hits = 0.0
    for r, w in zip(rows, windows):
        dens = {L: norm.logpdf(math.log(max(V.parse(s).value, 1e-6) / w), math.log(8.0), 0.4)
                - math.log(max(V.parse(s).value, 1e-6)) for L, s in r["Candidates"].items()}
        best = max(dens.values())
        top = [L for L, d in dens.items() if d == best]
        hits += (r["Answer"] in top) / len(top)
    return hits / len(rows)


def test_displacements_conditioned_on_the_window_defeat_the_implied_rate():
    rows, windows = _displacement_rows()
    out, ev, _ = build_options(iface=IFACE, records=rows, seed=0)
    acc = _implied_rate_attack(out, windows)
    assert binomtest(round(acc * len(out)), len(out), 0.2, alternative="greater").pvalue > 0.01, acc
    # the same attack against distractors drawn from the population of displacements, ignoring the
    # window, finds the answer far above chance: the test can fail
    rng = np.random.default_rng(1)
    pool = [r["Answer Detail"] for r in rows]
    naive = []
    for r in rows:
        others = [s for s in rng.choice(pool, 12) if s != r["Answer Detail"]][:4]
        c = dict(zip(LETTERS, [r["Answer Detail"], *others]))
        naive.append({**r, "Candidates": c, "Answer": "A"})
    assert _implied_rate_attack(naive, windows) > 0.4
    # every distractor is physically possible for a car over its window, and separated
    for r, w in zip(out, windows):
        vals = sorted(V.parse(s).value for s in r["Candidates"].values())
        assert max(vals) / w <= 45.0 + 1e-9
        assert all(b - a >= 0.01 - 1e-9 for a, b in zip(vals, vals[1:]))


def test_lattice_draw_is_exchangeable_and_spread():
    """Given the answer's score, the quantile lattice's other four are such that, over many answers, the
    answer's rank within its set is uniform and every candidate is a standard normal draw; neighbours are
    at least (1 - width)/5 apart in probability. A lattice at fixed offsets from the answer fails."""
    from scipy.stats import chisquare, kstest

    from resti_lib.options.population import lattice_scores

    rng = np.random.default_rng(0)
    z_a = rng.standard_normal((20000, 1))
    z = lattice_scores(z_a, 4, 0.5, rng)[:, :, 0]
    alls = np.column_stack([z_a, z])
    rank = (alls < z_a).sum(axis=1)  # the answer's rank among the five by value
    assert chisquare(np.bincount(rank, minlength=5)).pvalue > 1e-3
    assert kstest(z.ravel(), "norm").pvalue > 1e-3
    q = np.sort(norm.cdf(alls), axis=1)
    gaps = np.diff(np.column_stack([q, q[:, :1] + 1.0]), axis=1)  # around the circle of quantiles
    assert gaps.min() >= 0.1 - 1e-9
    # control: candidates at fixed quantile steps above the answer (wrapped) rank it first far too often
    naive = np.column_stack([z_a, norm.ppf((norm.cdf(z_a) + np.arange(1, 5) * 0.05) % 1.0)])
    assert chisquare(np.bincount((naive < z_a).sum(axis=1), minlength=5)).pvalue < 1e-6


def _coarse_speed_rows(n=300, seed=0):
    """Object speeds printed at 0.01 m/s with a median of 9 printed units (the coarse Omni6DPose case):
    the true distribution of printed units is known (``probs``)."""
    rng = np.random.default_rng(seed)
    units = np.arange(1, 31)
    w = np.exp(-0.5 * ((np.log(units) - math.log(9.0)) / 0.45) ** 2) / units
    probs = w / w.sum()
    rows = []
    for i in range(n):
        u = int(rng.choice(units, p=probs))
        # windows to the hundredth of a second: rows asking one window with one answer share a set, rarely here
        t0 = round(float(rng.uniform(0.0, 20.0)), 2)
        t1 = round(t0 + float(rng.uniform(2.0, 15.0)), 2)
        q = (f"What is the magnitude of the camera's average velocity (displacement divided by elapsed time) "
             f"between t={t0:g} s and t={t1:g} s? (unit: m/s)")
        rows.append(_row(i, "Speed & Acceleration", "Omni6DPose", q, V.format_scalar(u / 100.0, "m/s", 2),
                         video=f"{i:06d}.mp4", t0=t0, t1=t1))
    return rows, dict(zip(units.tolist(), probs.tolist()))


def test_coarse_speeds_take_the_lattice_and_the_most_typical_candidate_is_at_chance():
    rows, probs = _coarse_speed_rows()
    out, ev, _ = build_options(iface=IFACE, records=rows, seed=0)

    def typical(rs):  # the candidate most probable under the true distribution of printed units
        hits = 0.0
        for r in rs:
            p = {L: probs.get(round(V.parse(s).value * 100), 0.0) for L, s in r["Candidates"].items()}
            top = [L for L, x in p.items() if x == max(p.values())]
            hits += (r["Answer"] in top) / len(top)
        return hits / len(rs)

    acc = typical(out)
    assert binomtest(round(acc * len(out)), len(out), 0.2, alternative="greater").pvalue > 0.01, acc
    # the same reader against distractors spread wider than the answers (four other printed values drawn
    # uniformly over the range) finds the answer well above chance: the test can fail
    rng = np.random.default_rng(1)
    wide = []
    for r in rows:
        u = round(V.parse(r["Answer Detail"]).value * 100)
        others = rng.choice([x for x in range(1, 31) if x != u], 4, replace=False)
        c = [V.format_scalar(x / 100.0, "m/s", 2) for x in [u, *others]]
        wide.append({**r, "Candidates": dict(zip(LETTERS, c)), "Answer": "A"})
    assert typical(wide) > 0.4
    drawn = ev[ev["shared_with"].isna()] if "shared_with" in ev else ev  # a shared set was drawn for another row
    assert (drawn["draw"] == "lattice").all()  # a median answer of 9 printed units: coarse


def test_orientation_options_at_least_one_degree_apart():
    rng = np.random.default_rng(2)
    q = ("Between source pose timestamps 0.000000 and 19.800000 seconds, what is the signed horizontal "
         "heading change of the camera?")
    rows = [_row(i, "Ego-Centric Orientation", "Waymo", q, V.format_angle(float(rng.normal(0, 3.0))), t1=19.8)
            for i in range(80)]
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    for r in out:
        a = np.array([V.parse(s).value for s in r["Candidates"].values()])
        d = np.abs((a[:, None] - a[None, :] + 180.0) % 360.0 - 180.0)
        assert d[np.triu_indices(5, 1)].min() >= 1.0 - 1e-9, r["Candidates"]
        assert all(-180.0 <= x < 180.0 for x in a)
        assert ROW_CHECKS["separation"](parse_row(r, r["ReSTI ID"], IFACE)) is None
    # a planted pair half a degree apart is named by the separation check
    bad = dict(out[0])
    vals = sorted(V.parse(s).value for s in bad["Candidates"].values())
    other = next(L for L, s in bad["Candidates"].items() if L != bad["Answer"])
    bad["Candidates"] = {**bad["Candidates"], other: V.format_angle(V.parse(bad["Answer Detail"]).value + 0.5)}
    assert vals and "closer than the floor" in ROW_CHECKS["separation"](parse_row(bad, "x", IFACE))


def _box_rows(n=160, seed=3):
    """Boxes of one class whose log edges are strongly correlated (corr 0.9)."""
    rng = np.random.default_rng(seed)
    rows, logd = [], []
    cov = 0.09 * np.array([[1, 0.9, 0.9], [0.9, 1, 0.9], [0.9, 0.9, 1]])
    for i in range(n):
        ld = rng.multivariate_normal(np.log([1.8, 0.9, 0.8]), cov)
        c = [rng.uniform(-1, 1), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 5)]
        R = Rotation.from_euler("xz", [-90, rng.uniform(-180, 180)], degrees=True).as_matrix()
        q = (f"At {i}.0 seconds, what is the oriented 3D bounding box of the wooden table in the ScanNet "
             f"OpenCV camera frame (+X right, +Y down, +Z forward)?")
        rows.append(_row(i, "3D Video Grounding", "ScanNet", q, V.format_box(c, np.exp(ld), R),
                         video=f"scene{i:04d}_00.mp4", t0=float(i), t1=float(i)))
        logd.append(ld)
    return rows, np.array(logd), cov


def _desk_object_rows(n=160, seed=12):
    """Objects standing on a desk (their +Y axis along the desk's normal, turned at random about it) seen by
    cameras looking down at 30-60 degrees: in the OpenCV camera frame the object's +Y axis points up the image
    and towards the camera, ``(0, -cos e, -sin e)`` for elevation ``e``. Returns the rows and the elevations."""
    rng = np.random.default_rng(seed)
    rows, elev = [], []
    for i in range(n):
        e = rng.uniform(30, 60)
        # world: object y-up; camera: pitched down by e (OpenCV axes), the object turned by a random yaw
        R = (Rotation.from_euler("x", -e, degrees=True)
             * Rotation.from_euler("y", rng.uniform(-180, 180), degrees=True)).as_matrix()
        R = Rotation.from_euler("x", 180, degrees=True).as_matrix() @ R  # world y-up -> camera y-down
        c = [rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 1.2)]
        q = (f"At zero-based source frame {i} (30 FPS; video timestamp {i / 30:.6f} seconds), what is the "
             f"oriented 3D bounding box of the small mug in the OpenCV camera frame (+X right, +Y down, +Z forward)?")
        rows.append(_row(i, "3D Video Grounding", "Omni6DPose", q, V.format_box(c, rng.uniform(0.08, 0.2, 3), R),
                         video=f"desk{i:04d}.mp4", t0=i / 30, t1=i / 30))
        elev.append(e)
    return rows, np.array(elev)


@pytest.mark.parametrize("up_axis", ["auto", None])
def test_desk_objects_turn_about_their_up_axis(up_axis):
    """A reader who knows the law of the object's up axis in the camera frame (its angle from the image's up and
    towards the camera is the camera's elevation, 30-60 degrees) takes the candidate whose +Y axis is most
    nearly at that angle. With the axis found from the answers (``auto``: the most concentrated box axis) the
    distractors turn about the answer's own up axis and that reader is at chance; turned isotropically (null),
    the distractors tilt off the desk and the same reader finds the answer."""
    from resti_lib.geometry.fields import concentrated_axis

    rows, elev = _desk_object_rows()
    assert concentrated_axis([V.parse(r["Answer Detail"]).R for r in rows]) == 1
    iface = Interface(deep_merge(IFACE.options, {"kinds": {"box": {"up_axis": {"Omni6DPose": up_axis}}}}), IFACE.tasks)
    out, _, _ = build_options(iface=iface, records=rows, seed=0)
    hits = 0.0
    for r in out:
        # the +Y axis's elevation towards the camera and up the image: asin of its -Z component over cos of the
        # angle out of the image's vertical plane; the law's density is flat on 30-60 and falls off outside
        score = {}
        for k, s in r["Candidates"].items():
            y = np.array(V.parse(s).R)[:, 1]
            e = math.degrees(math.atan2(-y[2], -y[1])) if -y[1] > 0 else -90.0
            side = abs(y[0])
            score[k] = -(max(0.0, 30 - e, e - 60) + 100 * side)
        best = max(score.values())
        tied = [k for k, v in score.items() if v == best]
        hits += (r["Answer"] in tied) / len(tied)
    p = binomtest(int(round(hits)), len(out), 0.2, alternative="greater").pvalue
    if up_axis == "auto":
        assert p > 0.01, hits / len(out)
    else:
        assert p < 1e-3, hits / len(out)


MOUNT_YAW = {1: 0.0, 2: 45.0, 3: -45.0, 4: 90.0, 5: -90.0}   # Waymo camera mounts, by hand (+Y left)


def _road_box_rows(n=200, seed=5):
    """Waymo boxes of cars seen by the five cameras (half of them by the front one): nine in ten drive along
    the road (vehicle-frame heading 0 or 180 degrees, 3 degrees of spread), the rest at any heading. Each
    box is written in its camera's OpenCV frame. Returns the rows and each row's camera-to-vehicle rotation."""
    rng = np.random.default_rng(seed)
    rows, to_vehicle = [], []
    cams = rng.choice([1, 2, 3, 4, 5], size=n, p=[0.5, 0.15, 0.15, 0.1, 0.1])
    for i, cam in enumerate(cams):
        a = math.radians(MOUNT_YAW[int(cam)])
        # camera axes in the vehicle frame: +X right, +Y down, +Z the optical axis
        Rvc = np.column_stack([[math.sin(a), -math.cos(a), 0.0], [0.0, 0.0, -1.0], [math.cos(a), math.sin(a), 0.0]])
        h = (rng.choice([0.0, 180.0]) + rng.normal(0.0, 3.0)) if rng.random() < 0.9 else rng.uniform(-180, 180)
        R = Rvc.T @ Rotation.from_euler("z", h, degrees=True).as_matrix()
        c = [rng.uniform(-6, 6), rng.uniform(0.5, 1.8), rng.uniform(8, 40)]
        q = (f"At {i}.5 seconds, what is the oriented 3D bounding box of the parked sedan in an OpenCV camera "
             f"frame (+X right, +Y down, +Z forward)?")
        rows.append(_row(i, "3D Video Grounding", "Waymo", q, V.format_box(c, [4.6, 1.9, 1.5], R),
                         video=f"{1000 + i}_000_020_000_camera_{cam}.mp4", t0=i + 0.5, t1=i + 0.5))
        to_vehicle.append(Rvc)
    return rows, to_vehicle


@pytest.mark.parametrize("mounted", [True, False])
def test_waymo_box_headings_follow_the_named_camera(mounted):
    """A reader who knows the camera from the video name turns each candidate into the vehicle frame and takes
    the one nearest the road's axis. With headings drawn in the vehicle frame (``mount_frame``) the distractors
    of a side camera lie along the road as its answers do and that reader is at chance; drawn in the camera
    frame from a population of mostly front-camera boxes, a side camera's distractors lie where the front
    camera's cars are, across the road, and the reader finds the answer."""
    rows, to_vehicle = _road_box_rows()
    iface = Interface(deep_merge(IFACE.options, {"kinds": {"box": {"mount_frame": {"Waymo": mounted}}}}), IFACE.tasks)
    out, _, _ = build_options(iface=iface, records=rows, seed=0)
    by_rid = {r["ReSTI ID"]: r for r in out}
    hits, n, near = 0.0, 0, []
    for r0, Rvc in zip(rows, to_vehicle):
        r = by_rid[r0["ReSTI ID"]]
        if r0["Video"].endswith("camera_1.mp4"):
            continue
        off = {}
        for k, s in r["Candidates"].items():
            Rv = Rvc @ np.array(V.parse(s).R)
            h = math.degrees(math.atan2(Rv[1, 0], Rv[0, 0]))
            off[k] = min(abs((h + 90.0) % 180.0 - 90.0), 90.0)   # degrees off the road's axis
            if k != r["Answer"]:
                near.append(off[k] < 15.0)
        best = min(off.values())
        tied = [k for k, v in off.items() if v == best]
        hits += (r["Answer"] in tied) / len(tied)
        n += 1
    p = binomtest(int(round(hits)), n, 0.2, alternative="greater").pvalue
    if mounted:   # the side cameras' distractors lie along the road (their answers: about 0.9)
        assert np.mean(near) > 0.6 and p > 0.01, (np.mean(near), hits / n)
    else:
        assert np.mean(near) < 0.4 and p < 1e-4, (np.mean(near), hits / n)


def test_box_mount_frame_param_is_refused_by_name():
    rows, _ = _road_box_rows(n=30)
    iface = Interface(deep_merge(IFACE.options, {"kinds": {"box": {"mount_frame": {"Waymo": "yes"}}}}), IFACE.tasks)
    with pytest.raises(InputError) as e:
        build_options(iface=iface, records=rows, seed=0)
    assert e.value.field == "kinds.box.mount_frame.Waymo" and "options.yaml" in str(e.value)


def test_box_up_axis_param_is_refused_by_name():
    rows, _ = _desk_object_rows(n=30)
    iface = Interface(deep_merge(IFACE.options, {"kinds": {"box": {"up_axis": {"Omni6DPose": 5}}}}), IFACE.tasks)
    with pytest.raises(InputError) as e:
        build_options(iface=iface, records=rows, seed=0)
    assert e.value.field == "kinds.box.up_axis.Omni6DPose" and "options.yaml" in str(e.value)


def test_box_edges_drawn_jointly():
    rows, logd, cov = _box_rows()
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    dist = np.array([np.log(V.parse(s).lwh) for r in out for L, s in r["Candidates"].items() if L != r["Answer"]])
    corr = np.corrcoef(dist, rowvar=False)
    assert corr[0, 1] > 0.6 and corr[0, 2] > 0.6, corr
    # the true joint density of the edges picks the answer at chance
    inv = np.linalg.inv(cov)
    mu = np.log([1.8, 0.9, 0.8])
    hits = 0.0
    for r in out:
        sc = {L: -0.5 * (np.log(V.parse(s).lwh) - mu) @ inv @ (np.log(V.parse(s).lwh) - mu)
              for L, s in r["Candidates"].items()}
        best = max(sc.values())
        hits += (r["Answer"] in [L for L, v in sc.items() if v == best])
    assert binomtest(int(hits), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)
    for r in out:
        assert ROW_CHECKS["separation"](parse_row(r, r["ReSTI ID"], IFACE)) is None
        assert ROW_CHECKS["format_consistency"](parse_row(r, r["ReSTI ID"], IFACE)) is None


def _waymo_pose_row(i, P, T, w, cam=1):
    """A Waymo Pose question: the premise ``P`` at t=1 s, the answer ``T`` at t=1+w s, from camera
    ``cam``; returns the row and the premise as printed."""
    ptxt = V.format_pose(P, 2, compact=True)
    q = (f"Given the camera pose at t=1 s in the Waymo world coordinate frame: {ptxt}, what is the camera "
         f"pose in the same coordinate frame at t={1 + w:g} s?")
    return (_row(i, "Pose Estimation", "Waymo", q, V.format_pose(T, 2, compact=True),
                 video=f"seg{i}_camera_{cam}.mp4", t0=1 + w, t1=1 + w), V.parse(ptxt).matrix)


def test_poses_drawn_as_motion_from_the_premise():
    rng = np.random.default_rng(4)
    rows, prem = [], []
    for i in range(150):
        h = rng.uniform(-180, 180)
        Rp = Rotation.from_euler("zx", [h, -90], degrees=True).as_matrix()
        tp = rng.uniform(-1000, 1000, 3)
        w = float(rng.integers(2, 10))
        turn = rng.choice([0.0, 0.0, 0.0, rng.normal(0, 20)])
        R = Rotation.from_euler("z", turn, degrees=True).as_matrix() @ Rp
        fwd = Rp[:, 2] * np.array([1, 1, 0])
        fwd /= np.linalg.norm(fwd)
        t = tp + fwd * np.exp(rng.normal(math.log(9.0), 0.3)) * w
        P, T = np.eye(4), np.eye(4)
        P[:3, :3], P[:3, 3], T[:3, :3], T[:3, 3] = Rp, tp, R, t
        row, printed = _waymo_pose_row(i, P, T, w)
        rows.append(row)
        prem.append((printed, w))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    hits_near, hits_rate = 0.0, 0.0
    for r, (P, w) in zip(out, prem):
        d = {L: np.linalg.norm(np.array(V.parse(s).t) - P[:3, 3]) for L, s in r["Candidates"].items()}
        hits_near += r["Answer"] == min(d, key=d.get)
        dens = {L: norm.logpdf(math.log(max(x, 1e-6) / w), math.log(9.0), 0.3) for L, x in d.items()}
        hits_rate += r["Answer"] == max(dens, key=dens.get)
    for hits in (hits_near, hits_rate):
        assert binomtest(int(hits), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)
    for r in out:
        p = parse_row(r, r["ReSTI ID"], IFACE)
        assert ROW_CHECKS["separation"](p) is None  # includes: no two candidates print one rotation
        assert ROW_CHECKS["plausible_given_question"](p) is None
        assert ROW_CHECKS["format_consistency"](p) is None


def test_vehicle_cameras_on_other_mounts_are_drawn_apart():
    """A car's front camera sees it travel along the camera's optical axis; its side camera along the
    camera's x axis. A reader who knows the mean direction of travel of each camera in its own frame
    (other recordings' answers) takes the candidate whose motion from the premise, in the premise
    camera's frame, is most nearly along it. Drawn from one population of both mounts, every
    distractor's direction mixed the two, and that reader beat chance (old code: 0.29 of 240); each
    camera is now its own population."""
    rng = np.random.default_rng(8)
    rows, prem = [], []
    for i in range(240):
        cam, col = (1, 2) if i % 2 == 0 else (4, 0)
        Rp = Rotation.from_euler("ZX", [rng.uniform(-180, 180), -90], degrees=True).as_matrix()  # level OpenCV
        tp = rng.uniform(-1000, 1000, 3)
        w = float(rng.integers(2, 8))
        way = Rotation.from_euler("z", rng.normal(0, 3), degrees=True).as_matrix() @ Rp[:, col]
        t = tp + way * np.exp(rng.normal(math.log(9.0), 0.3)) * w
        P, T = np.eye(4), np.eye(4)
        P[:3, :3], P[:3, 3] = Rp, tp
        T[:3, :3], T[:3, 3] = Rotation.from_euler("z", rng.normal(0, 5), degrees=True).as_matrix() @ Rp, t
        row, printed = _waymo_pose_row(i, P, T, w, cam)
        rows.append(row)
        prem.append((printed, cam))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)

    def direction(P, s):
        d = P[:3, :3].T @ (np.array(V.parse(s).t) - P[:3, 3])
        return d / np.linalg.norm(d)

    answers = [direction(P, r["Candidates"][r["Answer"]]) for r, (P, _) in zip(out, prem)]
    hits = 0.0
    for i, (r, (P, cam)) in enumerate(zip(out, prem)):
        mean = np.mean([a for j, a in enumerate(answers) if j != i and prem[j][1] == cam], axis=0)
        cos = {L: float(direction(P, s) @ mean) for L, s in r["Candidates"].items()}
        hits += r["Answer"] == max(cos, key=cos.get)
    assert binomtest(int(hits), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)


# camera axes as releases print them: OpenCV (+Z forward, +Y down) and the Waymo camera frame (+X forward,
# +Z up, each camera a few tenths of a degree off level)
CAMERA_AXES = {
    "opencv": (lambda yaw, rng: Rotation.from_euler("zx", [yaw, -90], degrees=True).as_matrix(), 2),
    "waymo": (lambda yaw, rng: Rotation.from_euler("zyx", [yaw, rng.normal(0, 0.5), rng.normal(0, 0.5)],
                                                    degrees=True).as_matrix(), 0),
}


@pytest.mark.parametrize("axes", sorted(CAMERA_AXES))
def test_poses_before_their_premise_move_backwards_like_their_answers(axes):
    """A car moving forward, asked half the time for its pose *before* the premise time: the answer is
    then behind the premise. A reader who knows that (the direction of travel, signed by the time order
    the question prints) picks the answer at chance; mixing both time orders into one direction model
    would leave every backwards answer the one candidate behind the premise. The same holds whichever
    camera axes the release prints: in the Waymo camera frame the optical +Z is up, and a heading frame
    read off it turns with its small tilt, not with the car (the candidates then scatter around the
    premise while the answer lies ahead)."""
    rotation, fwd_col = CAMERA_AXES[axes]
    rng = np.random.default_rng(5)
    rows, prem = [], []
    for i in range(200):
        Rp = rotation(rng.uniform(-180, 180), rng)
        tp = rng.uniform(-1000, 1000, 3)
        w = float(rng.integers(2, 8))
        back = i % 2 == 1
        fwd = Rp[:, fwd_col] * np.array([1, 1, 0])
        fwd /= np.linalg.norm(fwd)
        way = Rotation.from_euler("z", rng.normal(0, 10), degrees=True).as_matrix() @ fwd  # a lane change
        t = tp + (-1.0 if back else 1.0) * way * np.exp(rng.normal(math.log(9.0), 0.3)) * w
        P, T = np.eye(4), np.eye(4)
        R = Rotation.from_euler("z", rng.normal(0, 15), degrees=True).as_matrix() @ Rp
        P[:3, :3], P[:3, 3], T[:3, :3], T[:3, 3] = Rp, tp, R, t
        ptxt = V.format_pose(P, 2, compact=True)
        tq = 10.0 - w if back else 10.0 + w
        q = (f"Given the camera pose at t=10 s in the Waymo world coordinate frame: {ptxt}, what is the camera "
             f"pose in the same coordinate frame at t={tq:g} s?")
        rows.append(_row(i, "Pose Estimation", "Waymo", q, V.format_pose(T, 2, compact=True),
                         video=f"seg{i}_camera_1.mp4", t0=tq, t1=tq))
        prem.append((V.parse(ptxt).matrix, -1.0 if back else 1.0))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)

    def forward(P):
        f = P[:3, fwd_col] * np.array([1, 1, 0])
        return f / np.linalg.norm(f)

    hits = 0.0
    for r, (P, sign) in zip(out, prem):
        f = forward(P)
        along = {L: sign * float(f @ (np.array(V.parse(s).t) - P[:3, 3])) for L, s in r["Candidates"].items()}
        hits += r["Answer"] == max(along, key=along.get)  # the farthest along the direction of time
    assert binomtest(int(hits), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)
    # the candidate whose displacement points most nearly along the direction of time (the outside
    # review's travel-direction reader)
    aligned = 0
    for r, (P, sign) in zip(out, prem):
        f = forward(P)
        cos = {}
        for L, s in r["Candidates"].items():
            d = sign * (np.array(V.parse(s).t) - P[:3, 3])
            cos[L] = float(f @ d) / max(float(np.linalg.norm(d)), 1e-9)
        aligned += r["Answer"] == max(cos, key=cos.get)
    assert binomtest(aligned, len(out), 0.2, alternative="greater").pvalue > 0.01, aligned / len(out)
    back = [r for r, (_, sign) in zip(out, prem) if sign < 0]
    behind = 0  # backwards rows: how many candidates lie behind the premise (the answer always does)
    for r, (P, sign) in zip(out, prem):
        if sign < 0:
            f = forward(P)
            behind += sum(float(f @ (np.array(V.parse(s).t) - P[:3, 3])) < 0 for s in r["Candidates"].values())
    # the distractors move backwards too: a candidate ahead of the premise would be one a reader who
    # knows that the car drives forward strikes off (a model of unsigned motion left 78 of 400 there)
    assert behind == 5 * len(back)


def test_rotation_preimage_prints_as_the_answer():
    rng = np.random.default_rng(5)
    for _ in range(50):
        R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        P = np.round(R, 2)
        Q = rotation_preimage(P, 2, rng)
        assert np.abs(Q @ Q.T - np.eye(3)).max() < 1e-9 and np.linalg.det(Q) > 0
        assert np.array_equal(np.round(Q, 2), P)


def test_rotation_preimage_keeps_the_printed_sign_of_a_zero():
    """A level camera's tilt entries print -0.0 or 0.0: with the sign kept, an entry printed -0.0 has a
    preimage below zero and one printed 0.0 one at or above it (each checked on the unrounded entry)."""
    rng = np.random.default_rng(9)
    seen = Counter()
    for _ in range(60):
        R = Rotation.from_euler("ZYX", [rng.uniform(-180, 180), rng.normal(0, 0.2), rng.normal(0, 0.2)],
                                degrees=True).as_matrix()
        P = np.round(R, 2)
        Q = rotation_preimage(P, 2, rng, signed_zero=True)
        assert np.array_equal(np.round(Q, 2), P)
        for z in zip(*np.nonzero(P == 0)):
            below = bool(Q[z] < 0)
            assert below == bool(np.signbit(P[z])), (z, P[z], Q[z])
            seen[below] += 1
    assert seen[True] > 10 and seen[False] > 10, seen  # both signs were exercised


@pytest.mark.parametrize("signed", [False, True])
def test_pose_distractors_print_zeros_as_the_answers_do(signed):
    """Level car cameras: the tilt entries round to zero in about a third of the prints. A release whose answers
    and premises never show -0.0 gets no distractor that does (one would be a distractor by its sign alone); a
    release that keeps the sign gets distractors with negative zeros at about the answers' rate."""
    rng = np.random.default_rng(11)
    rows = []
    for i in range(120):
        Rp = Rotation.from_euler("ZYX", [rng.uniform(-180, 180), *rng.normal(0, 0.3, 2)], degrees=True).as_matrix()
        R = Rotation.from_euler("ZYX", [rng.normal(0, 5), *rng.normal(0, 0.3, 2)], degrees=True).as_matrix() @ Rp
        tp = rng.uniform(-1000, 1000, 3)
        w = float(rng.integers(2, 8))
        t = tp + Rp[:, 0] * np.exp(rng.normal(math.log(9.0), 0.3)) * w
        P, T = np.eye(4), np.eye(4)
        P[:3, :3], P[:3, 3], T[:3, :3], T[:3, 3] = Rp, tp, R, t
        ptxt = V.format_pose(P, 2, compact=True, signed_zero=signed)
        q = (f"Given the camera pose at t=1 s in the Waymo world coordinate frame: {ptxt}, what is the camera "
             f"pose in the same coordinate frame at t={1 + w:g} s?")
        rows.append(_row(i, "Pose Estimation", "Waymo", q, V.format_pose(T, 2, compact=True, signed_zero=signed),
                         video=f"seg{i // 2}_camera_1.mp4", t0=1 + w, t1=1 + w))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)

    def zeros(text):  # (negative, all) zero entries of a printed pose
        vals = list(json.loads(text).values())
        return sum(v == 0 and math.copysign(1.0, v) < 0 for v in vals), sum(v == 0 for v in vals)

    ans = np.sum([zeros(r["Candidates"][r["Answer"]]) for r in out], axis=0)
    dis = np.sum([zeros(s) for r in out for k, s in r["Candidates"].items() if k != r["Answer"]], axis=0)
    assert ans[1] > 60 and dis[1] > 240, (ans, dis)  # zeros are common in both
    if not signed:
        assert ans[0] == 0 and dis[0] == 0, (ans, dis)
    else:  # the share of negative zeros among zeros, answers against distractors (two proportions)
        p1, p2 = ans[0] / ans[1], dis[0] / dis[1]
        pool = (ans[0] + dis[0]) / (ans[1] + dis[1])
        assert 0.2 < p1 < 0.8 and abs(p1 - p2) < 3 * math.sqrt(pool * (1 - pool) * (1 / ans[1] + 1 / dis[1])), (ans, dis)


def _desk_camera_rows(n=150, seed=13):
    """Hand-held cameras around a desk, each recording's first camera the reference: pitched 35-45 degrees down,
    all cameras level (x axis horizontal), looking at a point 0.8 m in front of the reference, from about
    that distance at other headings. The answer is the pose relative to the reference (OpenCV axes)."""
    rng = np.random.default_rng(seed)
    rows, downs = [], []
    for i in range(n):
        pitch = math.radians(rng.uniform(35, 45))
        down = np.array([0.0, math.cos(pitch), -math.sin(pitch)])   # the true down in the reference frame
        G = np.array([0.0, 0.0, 0.8])
        e1 = np.array([1.0, 0.0, 0.0])
        e2 = np.cross(down, e1)                                      # horizontal, towards the reference
        az = rng.uniform(-2.0, 2.0)
        horiz = math.cos(az) * e2 + math.sin(az) * e1
        C = G + 0.8 * math.cos(pitch) * horiz - 0.8 * math.sin(pitch) * down   # same height as the reference
        C += rng.normal(0, 0.03, 3)
        a = (G - C) / np.linalg.norm(G - C)
        x = np.cross(down, a)
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np.column_stack([x, np.cross(a, x), a]), C
        q = ("Taking the camera pose at t=0 s as the identity and expressing the result in the OpenCV camera frame "
             "of that instant (+X right, +Y down, +Z forward; translation in meters), what is the camera pose at "
             f"t={int(rng.integers(5, 40))} s?")
        rows.append(_row(i, "Pose Estimation", "Omni6DPose", q, V.format_pose(T, 2), video=f"{i:06d}.mp4",
                         t0=0.0, t1=5.0))
        downs.append(down)
    return rows, downs


def test_desk_cameras_are_drawn_level():
    """A reader who knows that hand-held cameras stay level and that reference cameras pitch down about 40
    degrees takes the candidate whose x axis is most nearly perpendicular to the mean down of the population.
    Drawn with the azimuth and roll about the reference's +Y, the distractors rolled with their place on the
    desk and that reader found the answer; drawn about the down the answers' x axes share
    (:func:`~resti_lib.geometry.fields.level_rotation`), it is at chance."""
    rows, downs = _desk_camera_rows()
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    down = np.mean(downs, axis=0)
    down /= np.linalg.norm(down)
    hits = 0.0
    for r in out:
        tilt = {k: abs(float(np.array(V.parse(s).R)[:, 0] @ down)) for k, s in r["Candidates"].items()}
        best = min(tilt.values())
        tied = [k for k, v in tilt.items() if v == best]
        hits += (r["Answer"] in tied) / len(tied)
    assert binomtest(int(round(hits)), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)


def test_pose_tilt_readout_is_the_printed_entry():
    """The echo readout of the two tilt fields (each drawn alone, the other fields at the answer) is the printed
    third-row entry of the rotation those fields make: ``r31`` for the first tilt, ``r32`` for the second about a
    level reference, ``r33`` about an OpenCV camera's -90 degrees (computed here from the rotation itself)."""
    from resti_lib.geometry.fields import from_yaw_tilt
    from resti_lib.options.kinds.pose import TILT_FIELDS, PoseKind

    rng = np.random.default_rng(10)
    up = [0.0, 0.0, 1.0]
    for tilt_ref, entry in ((0.0, (2, 1)), (-math.pi / 2, (2, 2))):
        n = 30
        yaw, b, lean = rng.uniform(-3, 3, n), rng.normal(0, 0.02, n), rng.normal(0, 0.02, n)
        F = np.zeros((n, 6))
        F[:, 3], F[:, TILT_FIELDS[0]], F[:, TILT_FIELDS[1]] = yaw, b, lean
        printed = PoseKind.tilt_readout(F, tilt_ref, [2] * n)
        draws = rng.normal(0, 0.03, (2, n, 5))  # (reps, rows, candidates) of one field
        for j, (r, c) in ((TILT_FIELDS[0], (2, 0)), (TILT_FIELDS[1], entry)):
            got = printed(draws, np.arange(n), j)
            for q in range(2):
                for i in range(n):
                    for k in range(5):
                        ang = [yaw[i], b[i], lean[i] + tilt_ref]
                        ang[1 if j == TILT_FIELDS[0] else 2] = draws[q, i, k] + (0.0 if j == TILT_FIELDS[0] else tilt_ref)
                        R = from_yaw_tilt(ang, up)
                        want = json.loads(V.format_pose(np.block([[R, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]]), 2))
                        assert got[q, i, k] == pytest.approx(want[f"r{r + 1}{c + 1}"], abs=1e-12)


def test_rows_of_one_video_asking_one_answer_share_their_candidates():
    rng = np.random.default_rng(6)
    q = "What is the width of the white refrigerator? (unit: m)"
    rows = [_row(i, "Dimensional Measurement", "ScanNet", q, V.format_scalar(float(rng.uniform(0.3, 2.0)), "m"),
                 video=f"scene{i % 20:04d}_00.mp4") for i in range(40)]
    rows.append({**rows[3], "ReSTI ID": "dup", "Legacy Row Key": "kdup", "time_start": 9.0, "time_end": 9.0})
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    assert sorted(out[3]["Candidates"].values()) == sorted(out[-1]["Candidates"].values())


def test_plausibility_and_format_checks_name_the_failing_candidate():
    q = "What is the displacement (straight-line distance) of the camera between t=2 s and t=2.1 s? (unit: m)"
    r = _row(0, "Displacement & Path Length", "Waymo", q, "1.20m", video="seg_camera_1.mp4", t0=2.0, t1=2.1)
    r["Candidates"] = {"A": "1.20m", "B": "0.80m", "C": "71.00m", "D": "2.40m", "E": "3.10m"}
    msg = ROW_CHECKS["plausible_given_question"](parse_row(r, "r0", IFACE))
    assert msg and msg.startswith("C:") and "71.00m" in msg
    r["Candidates"] = {"A": "1.20m", "B": "0.80m", "C": "1.700m", "D": "2.40m", "E": "3.10m"}
    msg = ROW_CHECKS["format_consistency"](parse_row(r, "r0", IFACE))
    assert msg and "C:" in msg


def test_repeated_answers_still_get_valid_options():
    # a group where every answer appears twice (a release repeated under new ids)
    rng = np.random.default_rng(7)
    base = [float(np.exp(rng.normal(2.5, 0.6))) for _ in range(60)]
    q = "What is the magnitude of the average velocity of the camera between t=3 s and t=9 s? (unit: m/s)"
    rows = [_row(i, "Speed & Acceleration", "Waymo", q, V.format_scalar(base[i % 60], "m/s"),
                 video=f"seg{i}_camera_1.mp4", t0=3.0, t1=9.0) for i in range(120)]
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    for r in out:
        p = parse_row(r, r["ReSTI ID"], IFACE)
        assert ROW_CHECKS["separation"](p) is None and ROW_CHECKS["distinct_strings"](p) is None


def test_same_input_and_seed_same_options():
    rows, _ = _displacement_rows(60)
    a, _, _ = build_options(iface=IFACE, records=rows, seed=1)
    b, _, _ = build_options(iface=IFACE, records=rows, seed=1)
    c, _, _ = build_options(iface=IFACE, records=rows, seed=2)
    assert json.dumps(a) == json.dumps(b) and json.dumps(a) != json.dumps(c)


def test_structural_leaks_and_evaluation_subset():
    labels = ["Front", "Front-Left", "Front-Right", "Left", "Right"]
    q = "What is the orientation of the camera mounted on the moving car relative to the car's forward direction?"
    rows = []
    cams = {1: "Front", 2: "Front-Left", 3: "Front-Right", 4: "Left", 5: "Right"}
    plan = [1] * 20 + [2] * 5 + [3] * 5 + [4] * 5 + [5] * 5  # Front in 20 of 40 rows
    for i, cam in enumerate(plan):
        rows.append(_row(i, "Spatial Relation", "Waymo", q, cams[cam], video=f"seg{i}_camera_{cam}.mp4",
                         labels=labels))
    leaks = structural_leaks(rows, IFACE)
    prior = leaks[leaks["leak"] == "label_prior"].iloc[0]
    assert prior["accuracy_on_affected"] == pytest.approx(20 / 40)
    meta = leaks[leaks["leak"] == "metadata"].iloc[0]
    assert meta["accuracy_on_affected"] == pytest.approx(1.0)  # the camera names the label
    sub = evaluation_subset(rows, IFACE, leaks)
    assert sub["n_kept"] == 0 and sub["dropped_by_reason"] == {"metadata": 40}
    # without the camera in the name, the subset balances the labels to the rarest one
    rows2 = [{**r, "Video": f"seg{i}.mp4"} for i, r in enumerate(rows)]
    sub2 = evaluation_subset(rows2, IFACE)
    kept = [r["Answer Detail"] for r in rows2 if r["ReSTI ID"] in set(sub2["ids"])]
    assert sorted(kept) == sorted(labels * 5)


def test_format_check_reads_an_ill_conditioned_heading():
    # a box whose x axis is nearly vertical: its heading atan2(R10, R00) cannot be recomputed from the
    # six-decimal entries, yet every candidate is printed by the one formatter from an exact rotation
    base = Rotation.from_euler("yz", [-89.997, -58.6], degrees=True).as_matrix()
    boxes = []
    for k in range(5):
        R = Rotation.from_euler("z", 7.0 * k, degrees=True).as_matrix() @ base
        boxes.append(V.format_box([-1.7 + 0.3 * k, 0.8, 10.6], [0.1, 0.84, 2.5 + 0.1 * k], R))
    v0 = V.parse(boxes[0])
    assert abs(V.wrap_degrees(v0.heading - V.box_heading(np.array(v0.R)))) > 0.05  # the heading is ill-conditioned
    q = ("At 3.0 seconds, what is the oriented 3D bounding box of the tall sign in the OpenCV frame of the FRONT camera "
         "(+X right, +Y down, +Z forward)?")
    r = _row(0, "3D Video Grounding", "Waymo", q, boxes[0], t0=3.0, t1=3.0)
    r["Candidates"] = dict(zip(LETTERS, boxes))
    assert ROW_CHECKS["format_consistency"](parse_row(r, "r0", IFACE)) is None
    # a candidate printed with a fourth decimal in its centre is named
    r["Candidates"]["C"] = r["Candidates"]["C"].replace("[-1.1,", "[-1.1004,")
    msg = ROW_CHECKS["format_consistency"](parse_row(r, "r0", IFACE))
    assert msg and msg.startswith("C:")


def _pose(tx: float) -> str:
    T = np.eye(4)
    T[:3, 3] = [tx, 0.0, 0.0]
    return V.format_pose(T, 2, compact=True)


def test_subset_counts_every_premise_reveal_and_answers_equal_to_their_premise():
    """Two questions printing the same premise (before: a dict kept only the last one), and an answer
    equal to its own premise: each is counted and dropped by name."""
    q = ("Given the camera pose at t=1 s in the Waymo world coordinate frame: {}, what is the camera pose in "
         "the same coordinate frame at t={} s?")
    v = "seg0_camera_1.mp4"
    rows = [
        _row(0, "Pose Estimation", "Waymo", q.format(_pose(0.0), 3), _pose(5.0), video=v, t0=3, t1=3),
        _row(1, "Pose Estimation", "Waymo", q.format(_pose(5.0), 4), _pose(9.0), video=v, t0=4, t1=4),
        _row(2, "Pose Estimation", "Waymo", q.format(_pose(5.0), 6), _pose(12.0), video=v, t0=6, t1=6),
        _row(3, "Pose Estimation", "Waymo", q.format(_pose(20.0), 7), _pose(20.0), video=v, t0=7, t1=7),
    ]
    leaks = structural_leaks(rows, IFACE)
    rev = leaks[leaks["leak"] == "same_video_reveal"].iloc[0]
    assert rev["rows_affected"] == 2  # r0 (printed by r1 and r2) and r3 (its own premise)
    sub = evaluation_subset(rows, IFACE, leaks)
    reasons = {d["id"]: d["reason"] for d in sub["dropped"]}
    assert reasons == {"r0": "same_video_reveal", "r3": "answer_is_premise"}
    assert sorted(sub["ids"]) == ["r1", "r2"] and sub["n_kept"] + len(sub["dropped"]) == len(rows)


def test_residual_rows_leave_out_both_questions_of_a_revealing_pair():
    """Two questions of one video, each printing the other's answer as its premise (t=1 -> t=3 and
    t=3 -> t=1): the subset keeps one of them, but a reader of the whole file still finds its answer in
    the other's question, so neither is a residual row. A zero answer above one in five is structural
    too; an unrelated pose and the rows trimmed only for label balance stay residual."""
    q = ("Given the camera pose at t={} s in the Waymo world coordinate frame: {}, what is the camera pose in "
         "the same coordinate frame at t={} s?")
    v = "seg0_camera_1.mp4"
    rows = [
        _row(0, "Pose Estimation", "Waymo", q.format(1, _pose(0.0), 3), _pose(5.0), video=v, t0=3, t1=3),
        _row(1, "Pose Estimation", "Waymo", q.format(3, _pose(5.0), 1), _pose(0.0), video=v, t0=1, t1=1),
        _row(2, "Pose Estimation", "Waymo", q.format(5, _pose(30.0), 9), _pose(41.0), video=v, t0=9, t1=9),
    ]
    sub = evaluation_subset(rows, IFACE)
    assert len(sub["ids"]) == 2 and "r2" in sub["ids"]  # one of the pair is kept
    assert residual_ids(rows, IFACE, sub) == ["r2"]
    # label balance trims a prior, no structural leak: those rows stay residual
    sub2 = {"ids": ["r0"], "dropped": [{"id": "r1", "reason": "label_balance"}, {"id": "r2", "reason": "zero_slot"}]}
    assert residual_ids(rows[2:], IFACE, sub2) == ["r0", "r1"]


def test_attack_table_scores_only_the_rows_it_is_asked_to():
    """Every row stays readable, only the named rows are scored: the answer is the smallest candidate
    in rows 0-19 and the largest in rows 20-39; scoring rows 0-9 and 30-39 counts 10 hits of 20 for
    the smallest-candidate rule, by hand."""
    rows = []
    for i in range(40):
        vals = [1.0 + k for k in range(5)]
        ans = 0 if i < 20 else 4
        r = _row(i, "Speed & Acceleration", "Waymo", "What is the magnitude of the camera's average velocity "
                 "between t=0 s and t=5 s? (unit: m/s)", V.format_scalar(vals[ans], "m/s"),
                 video=f"seg{i}_camera_1.mp4")
        r["Candidates"] = {L: V.format_scalar(x, "m/s") for L, x in zip(LETTERS, vals)}
        r["Answer"] = LETTERS[ans]
        rows.append(r)
    ids = [f"r{i}" for i in list(range(10)) + list(range(30, 40))]
    t = attack_table(rows, iface=IFACE, attacks=["min"], evaluate=ids)
    cell = t[(t["attack"] == "min") & (t["source"] == "Waymo")].iloc[0]
    assert (cell["n_rows"], cell["hits"]) == (20, 10)
    whole = attack_table(rows, iface=IFACE, attacks=["min"])
    assert whole[(whole["attack"] == "min") & (whole["source"] == "Waymo")].iloc[0]["hits"] == 20


def test_subset_keeps_one_of_each_converse_relation_pair():
    labels = ["Left", "Right", "Closer", "Farther", "Directly above"]
    q = ("Viewed from the camera at t=0 s: relative to the {}, is the {} to the left, to the right, closer to the "
         "camera, farther from the camera, or directly above? Choose the single dominant relation.")
    rows = [_row(0, "Spatial Relation", "Omni6DPose", q.format("teddy bear", "red suitcase"), "Left",
                 video="000001.mp4", t0=0, t1=0, labels=labels),
            _row(1, "Spatial Relation", "Omni6DPose", q.format("red suitcase", "teddy bear"), "Right",
                 video="000001.mp4", t0=0, t1=0, labels=labels),
            _row(2, "Spatial Relation", "Omni6DPose", q.format("teddy bear", "green truck"), "Right",
                 video="000001.mp4", t0=9, t1=9, labels=labels)]
    sub = evaluation_subset(rows, IFACE)
    assert {d["id"]: d["reason"] for d in sub["dropped"]}.get("r1") == "converse_pair"
    assert "r0" not in {d["id"] for d in sub["dropped"] if d["reason"] == "converse_pair"}


def test_subset_drops_angles_forced_by_the_one_degree_floor():
    """12 of 30 heading changes within 0.4 degrees of zero: only one candidate 1 degree apart from the
    others fits there, so those rows are dropped as floor_forced; the others are kept."""
    q = "By how many degrees did the camera's heading change between t=0 s and t=5 s? (unit: °)"
    near = [0.0, 0.1, -0.1, 0.2, -0.2, 0.3, -0.3, 0.05, -0.05, 0.15, -0.15, 0.35]
    far = [5.0 + 7.3 * k for k in range(18)]
    rows = [_row(i, "Ego-Centric Orientation", "Waymo", q, V.format_angle(x, 2), video=f"seg{i}_camera_1.mp4")
            for i, x in enumerate(near + far)]
    sub = evaluation_subset(rows, IFACE)
    forced = {d["id"] for d in sub["dropped"] if d["reason"] == "floor_forced"}
    assert forced == {f"r{i}" for i in range(len(near))}


def test_subset_drops_every_row_whose_candidates_touch_the_floor_window():
    """12 of 48 heading changes lie in a window narrower than the 1 degree floor; 20 of the 36 others
    carry a candidate in that window (0.3 degrees) as a distractor. Dropping only the window's answers
    would leave a subset where the window's candidate is never the answer; the subset drops every row
    whose candidates touch the window (a symmetric function of the candidate set, so the answer stays
    one of five in the rows kept): the 12 as floor_forced, the 20 as floor_window, the 16 others kept."""
    q = "By how many degrees did the camera's heading change between t=0 s and t=5 s? (unit: °)"
    near = [0.0, 0.1, -0.1, 0.2, -0.2, 0.3, -0.3, 0.05, -0.05, 0.15, -0.15, 0.35]
    rows = [_row(i, "Ego-Centric Orientation", "Waymo", q, V.format_angle(x, 2), video=f"seg{i}_camera_1.mp4",
                 labels=[V.format_angle(x + d, 2) for d in (0.0, 10.0, 20.0, 30.0, 40.0)])
            for i, x in enumerate(near)]
    for k in range(36):
        x = 5.0 + 2.9 * k
        other = 0.3 if k < 20 else -30.0
        rows.append(_row(len(rows), "Ego-Centric Orientation", "Waymo", q, V.format_angle(x, 2),
                         video=f"seg{len(rows)}_camera_1.mp4",
                         labels=[V.format_angle(y, 2) for y in (x, other, x + 50.0, x + 60.0, x + 70.0)]))
    sub = evaluation_subset(rows, IFACE)
    why = {d["id"]: d["reason"] for d in sub["dropped"]}
    assert {r for r, w in why.items() if w == "floor_forced"} == {f"r{i}" for i in range(12)}
    assert {r for r, w in why.items() if w == "floor_window"} == {f"r{i}" for i in range(12, 32)}
    assert sub["ids"] == [f"r{i}" for i in range(32, 48)]
    assert {"floor_forced", "floor_window"} <= set(STRUCTURAL_REASONS)


def test_adversarial_filter_reads_but_does_not_score_structural_rows():
    """12 of 48 heading changes lie within 0.4 degrees of zero, a window the 1 degree floor lets hold one
    candidate: the subset drops them as floor_forced (a structural leak: no option design hides it).
    A planted reader that names exactly those answers is one the filter must not chase: redrawing them
    cannot mend the leak and would hide it from the check. The filter scores the other rows only,
    finds nothing, and redraws nothing."""
    from resti_lib.options.attacks import ATTACKS, attack

    q = "By how many degrees did the camera's heading change between t=0 s and t=5 s? (unit: °)"
    near = [0.0, 0.1, -0.1, 0.2, -0.2, 0.3, -0.3, 0.05, -0.05, 0.15, -0.15, 0.35]
    far = [5.0 + 2.9 * k for k in range(36)]
    rows = [_row(i, "Ego-Centric Orientation", "Waymo", q, V.format_angle(x, 2), video=f"seg{i}_camera_1.mp4")
            for i, x in enumerate(near + far)]
    off = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 0}}), IFACE.tasks)
    drawn, _, _ = build_options(iface=off, records=rows, seed=0)
    forced = {d["id"] for d in evaluation_subset(drawn, off)["dropped"] if d["reason"] == "floor_forced"}
    assert forced == {f"r{i}" for i in range(len(near))}

    def dropped_rows(p):
        return frozenset(p.answer) if str(p.rid) in forced else None

    attack("test_forced_rows", ["angle"], "planted: the rows the subset drops as floor_forced")(dropped_rows)
    try:
        on = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 3, "attacks": ["test_forced_rows"]}}),
                       IFACE.tasks)
        out, ev, _ = build_options(iface=on, records=rows, seed=0)
    finally:
        ATTACKS.pop("test_forced_rows")
    log = ev.attrs["adversarial"]
    window = {d["id"] for d in evaluation_subset(drawn, off)["dropped"] if d["reason"] == "floor_window"}
    assert log[0]["rows_checked"] == len(rows) - len(forced) - len(window) and log[0]["significant_cells"] == []
    assert log[0]["stopped"] == "at chance" and len(log) == 1
    assert [r["Candidates"] for r in out] == [r["Candidates"] for r in drawn]  # nothing redrawn


def test_near_equal_answers_of_one_recording_get_translated_candidate_sets():
    """The camera videos of one segment ask one heading change and get answers 0.01-0.3 degrees
    apart: their candidate sets are translates of one set, so matching candidates across the rows
    (within half a degree) pairs every candidate, not only the answer."""
    q = "By how many degrees did the camera's heading change between t=0 s and t=19.8 s? (unit: °)"
    rng = np.random.default_rng(7)
    rows = []
    for seg in range(12):
        base = float(rng.uniform(-150, 150))
        for cam, d in zip((1, 2, 4), (0.0, 0.01, 0.3)):
            rows.append(_row(len(rows), "Ego-Centric Orientation", "Waymo", q, V.format_angle(base + d, 2),
                             video=f"seg{seg}_camera_{cam}.mp4", t0=0.0, t1=19.8))
    out, ev, _ = build_options(iface=IFACE, records=rows, seed=0)
    by_rid = {r["ReSTI ID"]: r for r in out}
    coupled = ev.dropna(subset=["coupled_with"]) if "coupled_with" in ev else ev.iloc[:0]
    assert len(coupled) == 24  # two of every three rows
    for rid, base in zip(coupled["rid"], coupled["coupled_with"]):
        a, b = by_rid[rid], by_rid[base]
        d = V.parse(a["Answer Detail"]).value - V.parse(b["Answer Detail"]).value
        xa = sorted(V.parse(s).value for s in a["Candidates"].values())
        xb = sorted(V.parse(s).value for s in b["Candidates"].values())
        assert np.allclose(np.array(xa) - np.array(xb), d, atol=0.011)  # a translate (printing aside)
        for L in LETTERS:  # every candidate has a partner within half a degree in the other set
            x = V.parse(a["Candidates"][L]).value
            assert min(abs(x - y) for y in xb) < 0.5
    for r in out:
        p = parse_row(r, r["ReSTI ID"], IFACE)
        assert ROW_CHECKS["separation"](p) is None and ROW_CHECKS["format_consistency"](p) is None


def test_adversarial_filter_redraws_the_rows_a_discriminator_identifies():
    """A planted discriminator that names the answer of every row where it is the largest candidate (an
    oracle: a fifth of exchangeable rows, each a sure hit): the filter finds its cell significant,
    draws new distractors for exactly the rows it identified (letters kept, every requirement met), and
    records its rounds; rows it did not identify keep their candidates."""
    from resti_lib.options.attacks import ATTACKS, attack

    rows, _ = _displacement_rows(n=120, seed=4)

    def tell(p):
        a = V.parse(p.candidates[p.answer]).value
        return frozenset(p.answer) if max(V.parse(s).value for s in p.candidates.values()) <= a else None

    attack("test_half_tell", ["scalar"], "planted: the answer where it is the largest candidate")(tell)
    try:
        off = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 0}}), IFACE.tasks)
        on = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 2, "attacks": ["test_half_tell"]}}),
                       IFACE.tasks)
        before, _, _ = build_options(iface=off, records=rows, seed=0)
        after, ev, _ = build_options(iface=on, records=rows, seed=0)
    finally:
        ATTACKS.pop("test_half_tell")
    told = {r["ReSTI ID"] for r in before
            if max(V.parse(s).value for s in r["Candidates"].values()) <= V.parse(r["Answer Detail"]).value}
    assert 10 <= len(told) <= 45  # about a fifth of 120 rows (counted from the strings)
    log = ev.attrs["adversarial"]
    assert log[0]["identified"] == len(told) and log[0]["significant_cells"][0]["attack"] == "test_half_tell"
    redrawn = set(ev.loc[ev["adversarial_redrawn"].notna(), "rid"]) if "adversarial_redrawn" in ev else set()
    assert redrawn >= told
    by_id = {r["ReSTI ID"]: r for r in before}
    for r in after:
        assert r["Answer"] == by_id[r["ReSTI ID"]]["Answer"]  # the letter schedule stays
        if r["ReSTI ID"] not in redrawn:
            assert r["Candidates"] == by_id[r["ReSTI ID"]]["Candidates"]
        p = parse_row(r, r["ReSTI ID"], on)
        assert ROW_CHECKS["separation"](p) is None and ROW_CHECKS["plausible_given_question"](p) is None


def test_object_speeds_are_not_drawn_from_the_cameras():
    """Waymo asks the average velocity of the camera (a driving car, about 8 m/s) and of objects, half of
    them parked (0.006-0.05 m/s: printed 0.01-0.05) and half driving. Drawn from one population of
    both, an object's distractors fill the speeds between the two modes, where no object is: a reader
    who knows the objects' speeds (the true density of log speed) takes the candidate it finds most
    probable. The camera's and the objects' magnitudes are separate populations, so that reader is
    at chance, and few distractors fall between the modes (old code: 0.50 of 120, p 9e-13)."""
    rng = np.random.default_rng(5)
    rows, objects = [], set()
    for i in range(240):
        t0, w = float(np.round(rng.uniform(1, 10), 1)), float(np.round(rng.uniform(1, 6), 1))
        if i % 2 == 0:
            q = (f"What is the magnitude of the camera's average velocity between t={t0:g} s and t={t0 + w:g} s, "
                 "computed as straight-line endpoint displacement divided by elapsed time? (unit: m/s)")
            v = float(np.exp(rng.normal(math.log(8.0), 0.4)))
        else:
            noun = ("suv", "sedan", "truck", "van")[i % 4 // 2 + 2 * (i % 3 == 0)]
            q = (f"What is the magnitude of the average velocity (displacement divided by elapsed time) of the "
                 f"{noun} between t={t0:g} s and t={t0 + w:g} s? (unit: m/s)")
            v = float(rng.uniform(0.006, 0.05)) if rng.random() < 0.5 else float(np.exp(rng.normal(math.log(8.0), 0.4)))
            objects.add(f"r{i}")
        rows.append(_row(i, "Speed & Acceleration", "Waymo", q, V.format_scalar(v, "m/s"),
                         video=f"seg{i}_camera_1.mp4", t0=t0, t1=t0 + w))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)

    def density(x):  # the objects' true density of log speed
        lx = math.log(max(x, 1e-4))
        parked = 0.5 / (math.log(0.05) - math.log(0.006)) if math.log(0.005) <= lx <= math.log(0.055) else 0.0
        return parked + 0.5 * norm.pdf(lx, math.log(8.0), 0.4)

    hits, between = 0.0, 0
    for r in out:
        if r["ReSTI ID"] not in objects:
            continue
        d = {L: density(V.parse(s).value) for L, s in r["Candidates"].items()}
        top = [L for L in d if d[L] == max(d.values())]
        hits += (r["Answer"] in top) / len(top)
        between += sum(0.1 < V.parse(s).value < 3 for L, s in r["Candidates"].items() if L != r["Answer"])
    assert binomtest(int(round(hits)), len(objects), 0.2, alternative="greater").pvalue > 0.01, hits / len(objects)
    assert between <= 0.15 * 4 * len(objects)


def test_adversarial_filter_names_a_leak_its_redraws_keep():
    """Redrawing the rows an attack got right leaves its misses: the cell then looks at chance whether
    the generator leaks or not. Two planted readers name the answer of the same 30 of 120 rows (every
    fourth row) in the first draw. One reads it from the row itself (as a premise printing its answer
    would): it names the answer again after any redraw, so the filter must stop with ``draw leaks``
    and name its cells, the 30 redrawn rows all hit. The other reads it from the first draw only
    (after a redraw it takes the largest candidate): the redrawn rows are at chance and the filter
    stops ``at chance`` with no leak named."""
    from resti_lib.options.attacks import ATTACKS, attack
    from resti_lib.release.reoption import filter_summary

    rows, _ = _displacement_rows(n=120, seed=4)
    chosen = {f"r{i}" for i in range(0, 120, 4)}
    off = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 0}}), IFACE.tasks)
    first = {r["ReSTI ID"]: r["Candidates"] for r in build_options(iface=off, records=rows, seed=0)[0]}

    def row_tell(p):
        return frozenset(p.answer) if str(p.rid) in chosen else None

    def draw_tell(p):
        if str(p.rid) not in chosen:
            return None
        if p.candidates == first[str(p.rid)]:
            return frozenset(p.answer)
        top = max(V.parse(s).value for s in p.candidates.values())
        return frozenset(L for L, s in p.candidates.items() if V.parse(s).value == top)

    logs = {}
    for name, fn in (("test_row_tell", row_tell), ("test_draw_tell", draw_tell)):
        attack(name, ["scalar"], "planted")(fn)
        try:
            on = Interface(deep_merge(IFACE.options, {"adversarial": {"rounds": 4, "attacks": [name]}}), IFACE.tasks)
            out, ev, _ = build_options(iface=on, records=rows, seed=0)
        finally:
            ATTACKS.pop(name)
        logs[name] = (ev.attrs["adversarial"], out)
    log, _ = logs["test_row_tell"]
    assert log[0]["identified"] == 30 and log[0]["redrawn"] == 30
    assert log[1]["stopped"] == "draw leaks" and log[1]["redrawn_rows_checked"] == 30
    assert {(c["attack"], c["source"], c["hits"], c["n"]) for c in log[1]["draw_leaks"]} == {
        ("test_row_tell", "Waymo", 30.0, 30), ("test_row_tell", "ALL", 30.0, 30)}
    line = filter_summary(log)  # what `resti reoption` prints
    assert "stopped: draw leaks" in line and "Displacement & Path Length/Waymo test_row_tell 30/30" in line
    log, out = logs["test_draw_tell"]
    # the largest candidate of each redrawn row, counted from the shipped strings
    top_hits = 0
    for r in out:
        if r["ReSTI ID"] in chosen:
            v = {L: V.parse(s).value for L, s in r["Candidates"].items()}
            top_hits += v[r["Answer"]] == max(v.values())
    assert top_hits <= 10  # near a fifth of 30
    assert log[0]["identified"] == 30
    assert log[-1]["stopped"] == "at chance" and all("draw_leaks" not in rec for rec in log)


def test_pose_distractors_lean_as_the_answers_lean():
    """Hand-held cameras of a scan stay nearly level (roll within a degree) while they turn and tilt: a
    distractor that rolls is one a reader who knows cameras are level strikes off (the outside review's
    reader: the candidate whose camera x axis is nearest horizontal, smallest |r31|). The tilts are
    drawn from level in world axes, so the distractors roll as little as the answers do. Counted a
    second way from the printed entries."""
    rng = np.random.default_rng(11)
    rows = []

    def camera(yaw, pitch):  # OpenCV axes (+X right, +Y down, +Z forward), world +Z up, roll within 1 deg
        return Rotation.from_euler("ZYX", [yaw, rng.normal(0, 1.0), -90 + pitch], degrees=True).as_matrix()

    for i in range(200):
        yaw, pitch = rng.uniform(-180, 180), rng.normal(-15, 10)
        P, T = np.eye(4), np.eye(4)
        P[:3, :3], P[:3, 3] = camera(yaw, pitch), rng.uniform(0, 6, 3)
        T[:3, :3] = camera(yaw + rng.normal(0, 40), pitch + rng.normal(0, 8))
        T[:3, 3] = P[:3, 3] + rng.normal(0, 0.6, 3)
        ptxt = V.format_pose(P, 2, compact=True)
        q = (f"Given the initial pose: {ptxt}, estimate and select the most likely camera pose at t=47 s in the same "
             "coordinate frame, using only the RGB video.")
        rows.append(_row(i, "Pose Estimation", "ScanNet", q, V.format_pose(T, 2, compact=True),
                         video=f"scene{i:04d}_00.mp4", t0=47.0, t1=47.0))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    r31 = lambda s: abs(float(json.loads(s)["r31"]))  # noqa: E731  the printed entry
    hits, answers, distractors = 0.0, [], []
    for r in out:
        v = {L: r31(s) for L, s in r["Candidates"].items()}
        tie = [L for L in v if v[L] == min(v.values())]
        hits += (r["Answer"] in tie) / len(tie)
        answers.append(v[r["Answer"]])
        distractors += [x for L, x in v.items() if L != r["Answer"]]
    assert binomtest(int(round(hits)), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)
    assert np.median(distractors) <= 1.5 * max(np.median(answers), 0.01)


def test_yaw_tilt_heading_and_lean_by_hand():
    """yaw_tilt reads a rotation as its heading about world up and two tilts: a level OpenCV camera
    turned 30 deg about +Z has heading 30 deg and tilts 0 and -90 deg (its +Z forward lies flat);
    turning it about the vertical changes only the heading; and from_yaw_tilt gives the rotation back,
    for another up axis too."""
    from resti_lib.geometry.fields import from_yaw_tilt, yaw_tilt

    level = Rotation.from_euler("z", 30, degrees=True).as_matrix() @ Rotation.from_euler("x", -90, degrees=True).as_matrix()
    assert np.degrees(yaw_tilt(level, [0, 0, 1])) == pytest.approx([30.0, 0.0, -90.0], abs=1e-9)
    turned = Rotation.from_euler("z", 25, degrees=True).as_matrix() @ level
    assert np.degrees(yaw_tilt(turned, [0, 0, 1])) == pytest.approx([55.0, 0.0, -90.0], abs=1e-9)
    for R in Rotation.random(20, random_state=3).as_matrix():
        for up in ([0, 0, 1], [0, 1, 0], [0.1, -0.2, 0.97]):
            assert from_yaw_tilt(yaw_tilt(R, up), up) == pytest.approx(R, abs=1e-12)


def _distance_rows(values: list) -> tuple[list, set]:
    """One surface-to-surface distance question per value, each in its own scene, and the ids of the
    rows whose answer prints at the floor (0.01 m)."""
    rows = [_row(i, "Dimensional Measurement", "ScanNet",
                 f"What is the minimum surface-to-surface distance between the chair number {i} and the table "
                 "next to it? (unit: m)", V.format_scalar(x, "m"), video=f"scene{i:04d}_00.mp4", t0=3.0, t1=3.0)
            for i, x in enumerate(values)]
    return rows, {f"r{i}" for i, x in enumerate(values) if V.format_scalar(x, "m") == "0.01m"}


def test_answers_at_the_printing_floor_are_slots_other_rows_carry():
    """Objects that touch print 0.01 m apart: nothing prints below that, so a floor answer drawn like
    the others is always the smallest candidate. It is a fixed slot instead, carried as a distractor by
    ``zero_slot_ratio`` (4) other rows per floor answer (old code: 0.01 m offered only where it is the
    answer). With 15 floor answers in 60 rows every row carries it, so it is the answer in a quarter of
    them: the structural table names it and the evaluation subset keeps floor answers at one in five
    (11 of the 45 others / 4), dropping 4 as ``zero_slot``."""
    rng = np.random.default_rng(8)
    rows, floor = _distance_rows([0.01 if i % 4 == 0 else float(np.exp(rng.normal(math.log(0.4), 0.8))) + 0.02
                                  for i in range(60)])
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    offered = [r for r in out if "0.01m" in r["Candidates"].values()]
    answered = {r["ReSTI ID"] for r in offered if r["Candidates"][r["Answer"]] == "0.01m"}
    assert answered == floor
    assert len(offered) == 60  # 15 answers and all 45 others (4 x 15 = 60 wanted)
    for r in offered:  # the smallest candidate in every row
        assert min(V.parse(s).value for s in r["Candidates"].values()) == 0.01
    leaks = structural_leaks(out, IFACE)
    slot = leaks[leaks["leak"] == "zero_slot"]
    assert len(slot) == 1 and slot["rows_affected"].iloc[0] == 60 and slot["accuracy_on_affected"].iloc[0] == 0.25
    sub = evaluation_subset(out, IFACE)
    dropped = {d["id"] for d in sub["dropped"] if d["reason"] == "zero_slot"}
    assert len(dropped) == 4 and dropped <= floor
    kept = [r for r in out if r["ReSTI ID"] in set(sub["ids"])]
    assert sum(r["Candidates"][r["Answer"]] == "0.01m" for r in kept) == 11 and len(kept) == 56


def test_a_population_narrower_than_the_floors_is_drawn_on_the_lattice():
    """Vehicle lengths: three in four are cars (4.7 m, 10%), one in four trucks (9 m, 30%), all asked of
    'the vehicle'. The middle half of the lengths spans fewer than 10 separation floors (3%), so five
    separated candidates cannot stay among the cars: the sets kept lean to the trucks' side and the
    answer is the smallest candidate (old code: 169 of 320, p 1e-38). Drawn on the quantile lattice,
    each of the five is the smallest alike."""
    q = ("What is the length of the vehicle? Length, width and height are the box dimensions along its "
         "heading, across it, and vertically. (unit: m)")
    ranks = np.zeros(5, int)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        rows = []
        for i in range(80):
            x = float(np.exp(rng.normal(math.log(4.7), 0.1) if i % 4 else rng.normal(math.log(9.0), 0.3)))
            rows.append(_row(i, "Dimensional Measurement", "Waymo", q, V.format_scalar(x, "m"),
                             video=f"seg{i}_camera_1.mp4", t0=1.0, t1=5.0))
        out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
        for r in out:
            v = sorted(V.parse(s).value for s in r["Candidates"].values())
            ranks[v.index(V.parse(r["Answer Detail"]).value)] += 1
    assert binomtest(int(ranks[0]), int(ranks.sum()), 0.2, alternative="greater").pvalue > 0.01, ranks
    assert chisquare(ranks).pvalue > 0.01, ranks


def test_a_trajectory_answer_keeps_the_rank_an_unconstrained_draw_gives_it():
    """Drives whose mean speed is uniform on 0.1-22 m/s: in log space the answers crowd below a sharp
    upper edge, with a long slow tail. Sets whose totals crowd closer than the 4% gap are rejected, and
    the sets that survive place the answer by where they could spread, not by chance (old code: ranks
    [52 51 92 94 71] and [57 46 82 75 100] on the seeds below, chi-square p 8e-5 and 5e-5). The answer
    keeps the rank it has in the first set the row draws, before any constraint, so over rows whose
    answers are calibrated each rank is as likely as the others."""
    q = ("Which option best describes the camera's movement trajectory between t=0 s and t={:g} s? Distances "
         "are path lengths along the trajectory and turns are net heading changes.")
    for seeds in ((0, 1, 2), (3, 4, 5)):
        ranks = np.zeros(5, int)
        for seed in seeds:
            rng = np.random.default_rng(seed)
            rows = []
            for i in range(120):
                w = float(np.round(rng.uniform(8, 20), 1))
                x = float(rng.uniform(0.1, 22)) * w
                rows.append(_row(i, "Trajectory Description", "Waymo", q.format(w),
                                 V.format_trajectory([("move", x)]), video=f"seg{i}_camera_1.mp4", t0=0.0, t1=w))
            out, ev, _ = build_options(iface=IFACE, records=rows, seed=0)
            for r in out:
                v = sorted(V.parse(s).total_distance for s in r["Candidates"].values())
                ranks[v.index(V.parse(r["Answer Detail"]).total_distance)] += 1
        assert chisquare(ranks).pvalue > 0.01, (seeds, ranks)
        for k in (0, 4):
            assert binomtest(int(ranks[k]), int(ranks.sum()), 0.2, alternative="greater").pvalue > 0.01, (seeds, ranks)


def test_a_dimension_learns_its_box_edge_and_its_class_from_other_recordings_boxes():
    """Waymo: the length asked of a sedan is the first edge of its grounding box in the same recording
    (four recordings agree, so ``box_edge_map`` takes edge 0). The class offset of a sedan's length
    then comes from the sedan boxes of the *other* recordings, never its own (its own box prints its
    answer), and not from the group's mean, which a bus pulls up."""
    from resti_lib.options.follow import box_edge_map
    from resti_lib.options.stage import Stage

    R = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    dq = ("What is the length of the {}? Length, width and height are the box dimensions along its heading, "
          "across it, and vertically. (unit: m)")
    bq = ("At 3.0 seconds, what is the oriented 3D bounding box of the {} in an OpenCV camera frame "
          "(+X right, +Y down, +Z forward)?")
    rows, i = [], 0
    lengths = {0: 4.41, 1: 4.62, 2: 4.83, 3: 4.50, 4: 4.70, 5: 4.58, 6: 4.66, 7: 4.45, 8: 12.0, 9: 13.5}
    asked = (0, 1, 8, 9)  # the other recordings hold a sedan box and no dimension question
    for k, L in lengths.items():
        noun = "bus" if L > 10 else "sedan"
        if k in asked:
            rows.append(_row(i, "Dimensional Measurement", "Waymo", dq.format(noun), V.format_scalar(L, "m"),
                             video=f"seg{k}_camera_1.mp4", t0=1.0, t1=5.0))
        rows.append(_row(i + 1, "3D Video Grounding", "Waymo", bq.format(noun),
                         V.format_box([1.0, 0.5, 12.0 + k], [L, 1.9, 1.5], R), video=f"seg{k}_camera_1.mp4",
                         t0=3.0, t1=3.0))
        i += 2
    st = Stage(rows, iface=IFACE, seed=0)
    assert box_edge_map(st.box_links.values(), {p.rid: p.spec for p in st.plans}) == {("Waymo", "length"): 0}
    g = next(p.group for p in st.plans if p.spec.task == "Dimensional Measurement")
    off = st.groups[g].info["offset"]
    eps = st.groups[g].info["eps"]
    sedans = [L for L in lengths.values() if L < 10]
    for k in (0, 1):
        others = [math.log(x + eps) for x in sedans if x != lengths[k]]  # 7 sedans of other recordings
        # they outnumber the shrinkage (3 pseudo-rows) towards the group's mean: within 0.4 m of their
        # mean (4.6 m). Without the boxes: the other sedan row and 3 pseudo-rows of the mean of it and
        # two buses, 7.7 m
        assert abs(math.exp(off[f"r{2 * k}"]) - math.exp(np.mean(others))) < 0.4
        assert math.exp(off[f"r{2 * k}"]) < 5.2


def test_distractors_take_only_values_that_recur_as_answers():
    """Objects asked in two recordings print one width twice, so distractors take such recurring
    answers as often as the answers do. Taking any other recording's answer instead spreads a value
    answered once into other rows as a distractor: a reader of the other recordings then sees the row's
    answer only as a distractor, and the candidate least often the answer elsewhere is the answer
    (old code: 0.39 of 200, p 1e-9)."""
    rng = np.random.default_rng(11)
    rows = []
    for i in range(200):
        x = float(np.exp(rng.normal(math.log(8.0), 0.5)))
        if i % 10 == 1:  # one object in two recordings (every tenth row and the next one)
            x = V.parse(rows[-1]["Answer Detail"]).value
        rows.append(_row(i, "Dimensional Measurement", "Omni6DPose", "What is the width of the mug? (unit: cm)",
                         V.format_scalar(x, "cm"), video=f"rec{i}_view.mp4", t0=1.0, t1=1.0))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    offered, answered = Counter(), Counter()
    for r in out:
        for L, s in r["Candidates"].items():
            offered[(r["Video"], s)] += 1
            answered[(r["Video"], s)] += L == r["Answer"]
    tot_o, tot_a = Counter(), Counter()
    for (_, s), n in offered.items():
        tot_o[s] += n
    for (_, s), n in answered.items():
        tot_a[s] += n
    hits = 0.0
    for r in out:  # each candidate's rate in the other recordings, shrunk to 1/5 by two pseudo-offers
        rate = {L: (tot_a[s] - answered[(r["Video"], s)] + 0.4) / (tot_o[s] - offered[(r["Video"], s)] + 2.0)
                for L, s in r["Candidates"].items()}
        low = [L for L in rate if rate[L] == min(rate.values())]
        hits += (r["Answer"] in low) / len(low)
    assert binomtest(int(round(hits)), len(out), 0.2, alternative="greater").pvalue > 0.01, hits / len(out)


def test_a_parked_cars_floor_speed_is_a_slot_beside_the_zero():
    """Object speeds: 15 parked cars at exactly 0, 15 at 0.01 m/s (the printing floor, just above the
    zero) and 70 others. Drawn like the others, 0.01 m/s is always the smallest candidate above the zero
    slot (old code, v5 Waymo Speed at seed 2: the answer in 8 of the 18 rows offering it, which the
    learned attacker read). Both are slots now, each carried by four other rows per answer: each is the
    answer in exactly one of the five rows that offer it."""
    rng = np.random.default_rng(12)
    rows = []
    for i in range(100):
        x = 0.0 if i % 20 < 3 else 0.01 if i % 20 < 6 else float(np.exp(rng.normal(math.log(1.5), 1.2))) + 0.02
        q = f"What is the speed of the suv number {i} at t=4 s? (unit: m/s)"
        rows.append(_row(i, "Speed & Acceleration", "Waymo", q, V.format_scalar(x, "m/s"),
                         video=f"seg{i}_camera_1.mp4", t0=4.0, t1=4.0))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    for slot in ("0.00m/s", "0.01m/s"):
        offered = [r for r in out if slot in r["Candidates"].values()]
        answered = [r for r in offered if r["Candidates"][r["Answer"]] == slot]
        assert len(answered) == 15 and len(offered) == 75, (slot, len(answered), len(offered))


def test_a_slot_answering_over_a_fifth_of_one_kind_of_question_is_structural_there():
    """Parked cars answer the instant speed of an object with 0.00 m/s, moving cars' average speeds
    over a window almost never do. The question shows which kind it is, so a zero that answers 4 of
    the 10 instant questions is the answer in 4 of at most 10 rows that print it, whatever the
    options, though it answers only 4 of the task's 60 speed rows (old code measured the share over
    the 60: no leak named, no zero dropped). The structural table names it for that kind of question;
    the evaluation subset keeps (10 - 4) // 4 = 1 of the 4 zeros, so the kept zero answers 1 of the
    7 kept rows that can carry it; the 50 window rows keep every row."""
    rng = np.random.default_rng(5)
    rows, zeros = [], set()
    for i in range(60):
        if i < 10:  # an object at an instant: four parked
            x = 0.0 if i < 4 else float(np.exp(rng.normal(math.log(6.0), 0.5)))
            q = f"What is the speed of the white truck number {i} at t=3 s? (unit: m/s)"
            t0 = t1 = 3.0
            if i < 4:
                zeros.add(f"r{i}")
        else:  # the camera over a window
            x = float(np.exp(rng.normal(math.log(9.0), 0.4)))
            t0, t1 = 2.0, 2.0 + float(np.round(rng.uniform(1.0, 9.0), 1))
            q = (f"What is the magnitude of the camera's average velocity between t={t0:g} s and t={t1:g} s, computed "
                 f"as straight-line endpoint displacement divided by elapsed time? (unit: m/s)")
        rows.append(_row(i, "Speed & Acceleration", "Waymo", q, V.format_scalar(x, "m/s"),
                         video=f"seg{i}_camera_1.mp4", t0=t0, t1=t1))
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    leaks = structural_leaks(out, IFACE)
    slot = leaks[leaks["leak"] == "zero_slot"]
    assert len(slot) == 1 and "object, at an instant" in slot["detail"].iloc[0], slot.to_dict("records")
    assert slot["accuracy_on_affected"].iloc[0] == pytest.approx(4 / 10)
    sub = evaluation_subset(out, IFACE)
    dropped = {d["id"] for d in sub["dropped"] if d["reason"] == "zero_slot"}
    assert len(dropped) == 3 and dropped <= zeros
    kept = {r["ReSTI ID"]: r for r in out if r["ReSTI ID"] in set(sub["ids"])}
    instant = [r for rid, r in kept.items() if int(rid[1:]) < 10]
    assert len(instant) == 7 and sum(r["Candidates"][r["Answer"]] == "0.00m/s" for r in instant) == 1
    assert all(f"r{i}" in kept for i in range(10, 60))


def test_a_row_whose_answer_is_a_slot_draws_its_other_candidates_on_the_lattice_too():
    """Surface distances of a few centimetres print coarsely, so the group is drawn on the quantile lattice:
    a row's candidates other than the slot (0.01 m) take one stratum each. A row whose answer *is* the slot
    has no drawn answer to place; it must still draw a lattice set (from a random start), or its other
    candidates cluster (old code: an anchor and a narrow spread) and the tightest sets give the slot away.

    Blind rule: among the rows that offer 0.01 m, call it the answer in as many rows as there are
    floor answers, those whose other candidates spread least (log values). By hand, a rule that knows
    nothing hits 8 x 8/40 = 1.6 floor answers per build (hypergeometric), 6.4 over four builds (sd 2.0);
    the old code hits 29 of 32."""
    hits = []
    for seed in range(4):
        rng = np.random.default_rng(3 + seed)
        rows, floor = _distance_rows([0.01 if i % 10 == 0 else max(0.02, float(np.exp(rng.normal(math.log(0.05), 0.6))))
                                      for i in range(80)])
        out, _, _ = build_options(iface=IFACE, records=rows, seed=seed)
        offered = [r for r in out if "0.01m" in r["Candidates"].values()]
        assert len(offered) == 40 and len(floor) == 8
        spread = {r["ReSTI ID"]: float(np.std([math.log(V.parse(s).value) for s in r["Candidates"].values()
                                               if s != "0.01m"])) for r in offered}
        tight = sorted(spread, key=lambda k: (spread[k], k))[:len(floor)]
        hits.append(len(set(tight) & floor))
    assert sum(hits) <= 12, hits  # 2.8 sd above the 6.4 expected by chance


def test_a_floor_slot_is_the_only_candidate_printed_at_the_floor():
    """Where the printing floor (0.01 m) is a fixed slot, no row draws a candidate printed there: the
    floor is offered exactly as the slot design says, by the 8 floor answers and 4 carriers per floor
    answer, 40 rows of 80 (by hand). Drawn floor values beside the slot (old code: 58 rows offered it
    here) crowd the bottom of every set with strings that are rarely the answer, and a carrier row
    whose drawn candidate collides with its slot is redrawn, so its answer sits lower than its
    distractors more often than by chance."""
    rng = np.random.default_rng(3)
    rows, floor = _distance_rows([0.01 if i % 10 == 0 else max(0.02, float(np.exp(rng.normal(math.log(0.05), 0.6))))
                                  for i in range(80)])
    out, _, _ = build_options(iface=IFACE, records=rows, seed=0)
    offered = [r for r in out if "0.01m" in r["Candidates"].values()]
    assert {r["ReSTI ID"] for r in offered if r["Candidates"][r["Answer"]] == "0.01m"} == floor
    assert len(offered) == 8 * (1 + 4)


def test_every_kind_builds_after_one_kind_module_is_imported_alone():
    """Importing one kind's module for a helper (a test of the box's depth exponent) registers that kind only;
    the stage must still find every other kind's builder, whatever ran first in the process."""
    import subprocess
    import sys

    code = ("import resti_lib.options.kinds.box\n"
            "from resti_lib.options.kinds import builder_for\n"
            "print(sorted(type(builder_for(k)).__name__ for k in ('scalar', 'angle', 'trajectory', 'box', 'pose', 'label')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(sorted(["ScalarKind", "AngleKind", "TrajectoryKind", "BoxKind", "PoseKind",
                                             "LabelKind"])), out.stdout
