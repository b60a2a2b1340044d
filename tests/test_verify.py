"""resti verify: reproduces ReSTI v5's release.json with every check passing; corrupted copies fail
by name, with the failing rows."""

import json
import re
import shutil
from collections import Counter

import numpy as np
import pytest

from resti_lib.release.verify import verify_path
from resti_lib.run.cli import main as cli_main


def test_v5_reproduces_release_json(resti_v5_dir):
    v = verify_path(resti_v5_dir)
    meta = json.loads((resti_v5_dir / "release.json").read_text())
    assert v["accepted_rows"] == 1782 == meta["counts"]["accepted"]
    assert v["excluded_rows"] == 282 == meta["counts"]["excluded"]
    assert v["by_task"] == meta["accepted_by_task"]
    assert v["by_source"] == meta["accepted_by_source"]
    assert v["answer_letters"] == {"A": 357, "B": 357, "C": 357, "D": 357, "E": 354}
    assert v["excluded_by_task"] == meta["excluded_by_task"]
    failing = {k: c for k, c in v["checks"].items() if c["status"] == "fail"}
    # v5 meets every structural check; the answer-interface requirements name its defects (below)
    assert set(failing) == {"separation", "plausible_given_question"}
    assert v["checks"]["sha256"]["status"] == "pass"
    assert not v["passed"]


def _rotation_text(s: str) -> tuple:
    obj = json.loads(s)
    return tuple(obj[k] for k in ("r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33"))


def test_v5_answer_interface_defects_named(resti_v5_dir):
    """The rows verify names are the rows a reading of the strings finds: Pose candidates printing one
    rotation, and distractors no vehicle could reach within the question's window."""
    rows = [json.loads(line) for line in open(resti_v5_dir / "resti.jsonl", encoding="utf-8")]
    v = verify_path(resti_v5_dir)
    repeated = {r["ReSTI ID"] for r in rows if r["Task"] == "Pose Estimation"
                and len({_rotation_text(s) for s in r["Candidates"].values()}) < 5}
    assert repeated and repeated <= set(v["checks"]["separation"]["failing"])
    impossible = set()
    for r in rows:
        window = r["time_end"] - r["time_start"]
        if r["Task"] == "Trajectory Description" and 0 < window:
            for s in r["Candidates"].values():
                total = sum(float(x) for x in re.findall(r"move forward ([0-9.]+)m", s))
                answer = sum(float(x) for x in re.findall(r"move forward ([0-9.]+)m", r["Answer Detail"]))
                if total > max(45.0 * window, 1.25 * answer):  # 45 m/s: params/options.yaml, Waymo
                    impossible.add(r["ReSTI ID"])
    assert impossible and impossible <= set(v["checks"]["plausible_given_question"]["failing"])


def test_v5_counts_by_independent_reading(resti_v5_dir):
    rows = [json.loads(line) for line in open(resti_v5_dir / "resti.jsonl", encoding="utf-8")]
    v = verify_path(resti_v5_dir)
    assert v["answer_letters"] == dict(sorted(Counter(r["Answer"] for r in rows).items()))


@pytest.fixture
def v5_copy(resti_v5_dir, tmp_path):
    dst = tmp_path / "v5"
    shutil.copytree(resti_v5_dir, dst)
    rows = [json.loads(line) for line in open(dst / "resti.jsonl", encoding="utf-8")]
    return dst, rows


def _write(dst, rows):
    (dst / "resti.jsonl").write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in rows),
                                     encoding="utf-8")


def _first(rows, task):
    return next(i for i, r in enumerate(rows) if r["Task"] == task)


def test_corrupted_copy_names_each_failure_and_row(v5_copy):
    dst, rows = v5_copy
    # 1. key-detail mismatch: point the key at another letter
    i = _first(rows, "Ego-Centric Orientation")
    rows[i]["Answer"] = "A" if rows[i]["Answer"] != "A" else "B"
    # 2. exact duplicate candidates
    j = _first(rows, "Displacement & Path Length")
    other = next(k for k in "ABCDE" if k != rows[j]["Answer"])
    dup_of = next(k for k in "ABCDE" if k not in (other, rows[j]["Answer"]))
    rows[j]["Candidates"][other] = rows[j]["Candidates"][dup_of]
    # 3. numeric duplicate: same value, different text (0.1m vs 10cm style)
    k = _first(rows, "Speed & Acceleration")
    a, b = [x for x in "ABCDE" if x != rows[k]["Answer"]][:2]
    val = float(rows[k]["Candidates"][a].rstrip("m/s²"))
    unit = "m/s²" if rows[k]["Candidates"][a].endswith("²") else "m/s"
    rows[k]["Candidates"][b] = f"{val:.3f}{unit}"
    # 4. reflected rotation in a pose answer
    p = _first(rows, "Pose Estimation")
    pose = json.loads(rows[p]["Answer Detail"])
    for c in ("r11", "r21", "r31"):
        pose[c] = -pose[c]
    text = json.dumps(pose)
    rows[p]["Answer Detail"] = text
    rows[p]["Candidates"][rows[p]["Answer"]] = text
    # 5. reversed times
    q = _first(rows, "Trajectory Description")
    rows[q]["time_start"], rows[q]["time_end"] = 5.0, 1.0
    # 6. NaN in a candidate
    s = _first(rows, "Dimensional Measurement")
    bad = next(x for x in "ABCDE" if x != rows[s]["Answer"])
    rows[s]["Candidates"][bad] = "nanm"
    _write(dst, rows)
    v = verify_path(dst)
    c = v["checks"]
    assert not v["passed"]
    assert c["key_detail_agreement"]["failing"] == [rows[i]["ReSTI ID"]]
    assert c["distinct_strings"]["failing"] == [rows[j]["ReSTI ID"]]
    assert c["numeric_duplicates"]["failing"] == [rows[k]["ReSTI ID"]]
    assert c["rotation_validity"]["failing"] == [rows[p]["ReSTI ID"]]
    assert c["time_order"]["failing"] == [rows[q]["ReSTI ID"]]
    assert c["finite_values"]["failing"] == [rows[s]["ReSTI ID"]]
    # the rewritten file no longer matches its digests; release.json letters changed
    assert c["sha256"]["status"] == "fail" and "resti.jsonl" in c["sha256"]["failing"]
    assert c["release_json"]["status"] == "fail" and "answer_letters" in c["release_json"]["failing"]


def test_overlap_and_duplicate_ids(v5_copy):
    dst, rows = v5_copy
    excluded = [json.loads(line) for line in open(dst / "excluded.jsonl", encoding="utf-8")]
    rows[1]["ReSTI ID"] = rows[0]["ReSTI ID"]
    rows[2]["Legacy Row Key"] = excluded[0]["key"]
    _write(dst, rows)
    v = verify_path(dst)
    assert rows[0]["ReSTI ID"] in v["checks"]["unique_ids"]["failing"]
    assert v["checks"]["accepted_excluded_disjoint"]["failing"] == [excluded[0]["key"]]


def test_rotation_tolerance_matches_rounding():
    from resti_lib.options.checks import rotation_tolerance

    # an exact rotation rounded to 2 decimals must pass; a 5% shear must fail
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    for R in Rotation.random(200, random_state=1).as_matrix():
        Rr = np.round(R, 2)
        assert np.abs(Rr @ Rr.T - np.eye(3)).max() <= rotation_tolerance(2)
    S = np.eye(3)
    S[0, 1] = 0.05
    assert np.abs(S @ S.T - np.eye(3)).max() > rotation_tolerance(2)
    del rng


def test_cli_verify_json_exit_codes(v5_copy, capsys):
    """``resti verify`` in-process (the entry point's own process is checked in test_cli)."""
    dst, rows = v5_copy
    code = cli_main(["verify", str(dst), "--json"])
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    failing = {k for k, c in out["checks"].items() if c["status"] == "fail"}
    assert code == 1 and failing == {"separation", "plausible_given_question"}, cap.err
    assert {"accepted_rows", "excluded_rows", "by_task", "by_source", "answer_letters", "checks"} <= set(out)
    rows[0]["Candidates"]["A"] = rows[0]["Candidates"]["B"]
    _write(dst, rows)
    code = cli_main(["verify", str(dst)])
    text = capsys.readouterr().out
    assert code == 1 and "FAIL" in text and rows[0]["ReSTI ID"] in text
