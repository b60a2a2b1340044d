"""Dimensional Measurement: operators by hand, phrase reading, and acceptance on the mini-world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from resti_lib import measure as M
from resti_lib.sources import referents as R
from resti_lib.sources.scannet import OrientedBox
from tests import scalar_helpers as H
from tests.test_sources_omni6d import SCENE as ROPE_SCENE
from tests.test_sources_omni6d import write_rope
from tests.test_sources_scannet import SCENE as SN_SCENE
from tests.test_sources_scannet import write_scene
from tests.test_sources_waymo import SEG, write_segment

TASK = "Dimensional Measurement"


def rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box(center, lwh, R=None) -> OrientedBox:
    return OrientedBox(np.asarray(center, float), np.eye(3) if R is None else np.asarray(R, float),
                       np.asarray(lwh, float))


# ------------------------------------------------------------------------------- geometry by hand


def test_point_box_distance_by_hand():
    b = box([0, 0, 0], [2, 4, 6])
    assert R.point_box_distance([3, 0, 0], b.center, b.R, b.lwh)[0] == pytest.approx(2.0)
    assert R.point_box_distance([2, 3, 4], b.center, b.R, b.lwh)[0] == pytest.approx(math.sqrt(3))
    assert R.point_box_distance([0.5, 0.5, 0.5], b.center, b.R, b.lwh)[0] == 0.0  # inside
    # rotated 90 deg about z: the 2 m side now runs along world y, so x reaches +-2
    d, nearest = R.point_box_distance([3, 0, 0], [0, 0, 0], rz(90), [2, 4, 6])
    assert d == pytest.approx(1.0) and nearest == pytest.approx([2, 0, 0])


def test_box_box_distance_by_hand():
    a = box([0.5, 0.5, 0.5], [1, 1, 1])
    assert R.box_box_distance(a, box([3.5, 0.5, 0.5], [1, 1, 1]))[0] == pytest.approx(2.0)
    assert R.box_box_distance(a, box([2.5, 2.5, 0.5], [1, 1, 1]))[0] == pytest.approx(math.sqrt(2))
    assert R.box_box_distance(a, box([1.2, 0.5, 0.5], [1, 1, 1]))[0] == 0.0  # overlap
    # a unit cube turned 45 deg about z, centred 2 m away: its nearest edge is at x = 2 - sqrt(2)/2
    c = box([0, 0, 0], [1, 1, 1])
    d, pa, pb = R.box_box_distance(c, box([2, 0, 0], [1, 1, 1], rz(45)))
    assert pa[0] == pytest.approx(0.5)
    assert d == pytest.approx(2 - math.sqrt(2) / 2 - 0.5, abs=1e-9)
    assert pb[0] == pytest.approx(2 - math.sqrt(2) / 2, abs=1e-9)


def test_box_visibility_frustum():
    intr = {"fx": 100.0, "fy": 100.0, "cx": 50.0, "cy": 50.0, "width": 100, "height": 100}
    ahead = R.box_visibility(box([0, 0, 5], [1, 1, 1]), intr)
    assert ahead["visible"] and ahead["fraction"] == 1.0 and ahead["centre_in_view"]
    behind = R.box_visibility(box([0, 0, -5], [1, 1, 1]), intr)
    assert not behind["visible"] and behind["all_behind"]
    aside = R.box_visibility(box([40, 0, 5], [1, 1, 1]), intr)  # projects far right of the image
    assert not aside["visible"] and aside["n_in_view"] == 0
    far = R.box_visibility(box([0, 0, 50], [1, 1, 1]), intr, far=20.0)
    assert not far["visible"]


# ------------------------------------------------------------------------------------ phrases


@pytest.mark.parametrize("text, grouped", [
    ("the two black office chairs", "plural"), ("Both chairs along the wall", "both"),
    ("the pair of trash cans", "pair of"), ("the set of bottles", "set of"),
    ("White door with two black handles, wooden frame", None), ("A small brown teddy bear wearing a blue shirt", None),
    ("Beige three-seat sofa with cushions", None),
])
def test_group_markers(text, grouped):
    ph = R.read_phrase(text)
    _, plural, _ = R.match_labels(ph, ["chair", "trash can", "bottle", "door", "teddy bear", "sofa"])
    assert (ph.grouped or ("plural" if plural else None)) == grouped


def test_label_matching_head_noun_and_plural():
    labels = ["chair", "armchair", "table", "trash can", "tv stand", "door"]
    assert R.match_labels(R.read_phrase("Brown leather armchair in the corner"), labels)[:2] == ("armchair", False)
    assert R.match_labels(R.read_phrase("Black tv stand under the television"), labels)[:2] == ("tv stand", False)
    assert R.match_labels(R.read_phrase("chairs by the table"), labels)[:2] == ("chair", True)
    assert R.match_labels(R.read_phrase("Black upright piano against the wall"), labels)[0] is None
    assert R.match_labels(R.read_phrase("A couch"), ["sofa"])[0] == "sofa"  # synonym


def test_waymo_noun_classes():
    assert R.waymo_noun(R.read_phrase("A red pickup truck with a black bed cover"))[0] == "pickup truck"
    assert R.waymo_noun(R.read_phrase("A small green hatchback car"))[0] == "hatchback"
    assert R.waymo_noun(R.read_phrase("A pedestrian in a red jacket"))[1] == "TYPE_PEDESTRIAN"
    assert R.waymo_noun(R.read_phrase("A horse-drawn carriage"))[0] is None
    _, typ, rng = R.waymo_noun(R.read_phrase("A red double-decker bus"))
    assert typ == "TYPE_VEHICLE" and not R.size_fits([12.0, 2.6, 3.2], rng)  # a school bus is too low


def test_unsupported_questions_get_specific_reasons():
    from resti_lib.tasks.base import Outcome
    from resti_lib.tasks.dimensional import unsupported

    def reasons(q):
        o = unsupported(q).apply(Outcome(0, "k", TASK, "ScanNet", "v", 0, "retained"))
        return o.reasons, o.defects

    assert reasons("What is the diameter of the white bowl?") == (["undefined_dimension"], [])
    assert reasons("What is the distance between the two black chairs?") == (["grouped_referent"],
                                                                                 ["grouped_referent"])
    assert reasons("What color is the sofa?") == (["unsupported_question"], [])


# ------------------------------------------------------------------- resti measure operators


@pytest.fixture(scope="module")
def roots(tmp_path_factory):
    base = tmp_path_factory.mktemp("dim_sources")
    write_scene(base / "scans")
    write_segment(base / "waymo")
    write_rope(base / "omni6d")
    return {"scannet_root": str(base / "scans"), "waymo_root": str(base / "waymo"),
            "omni6d_root": str(base / "omni6d")}


def test_measure_dimension_and_camera_distance_scannet(roots):
    # instance 0: raw box [0,2]x[0,1]x[0,1]; the camera sits at raw (1, -3, 0.5) at frame 0, (1, -2, 0.5) at 1
    c = {"source": "ScanNet", "sequence": SN_SCENE, "entity": {"kind": "object", "id": 0}, "times": [0.0],
         "operator": "dimension"}
    r = M.evaluate_contract(c, roots)
    assert r["value"] == pytest.approx({"length": 2.0, "width": 1.0, "height": 1.0})
    r = M.evaluate_contract({**c, "operator": "distance_to_camera"}, roots)
    assert r["value"] == pytest.approx(3.0) and r["unit"] == "m"  # nearest box point (1, 0, 0.5)
    assert r["evidence"]["visibility"]["visible"]
    r = M.evaluate_contract({**c, "operator": "distance_to_camera", "times": [1 / 30], "unit": "cm"}, roots)
    assert r["value"] == pytest.approx(200.0) and r["unit"] == "cm"
    r = M.evaluate_contract({**c, "operator": "distance_to_camera", "times": [2 / 30]}, roots)
    assert "invalid" in r["error"]


def test_measure_waymo_box(roots):
    # camera 1.5 m ahead of the rear axle, 2 m up; box centre 5 m ahead (+1 m per frame), 1 m up, 4.5 x 2 x 1.6
    c = {"source": "Waymo", "sequence": SEG, "camera": "FRONT", "entity": {"kind": "object", "id": "obj-a"},
         "times": [0.0], "operator": "distance_to_camera"}
    r = M.evaluate_contract(c, roots)
    assert r["value"] == pytest.approx(math.hypot(2.75 - 1.5, 2.0 - 1.8))  # nearest point (2.75, 0, 1.8)
    r = M.evaluate_contract({**c, "times": [0.2]}, roots)
    assert r["value"] == pytest.approx(math.hypot(4.75 - 1.5, 0.2))
    r = M.evaluate_contract({**c, "operator": "dimension"}, roots)
    assert r["value"] == pytest.approx({"length": 4.5, "width": 2.0, "height": 1.6})


def test_measure_omni_box(roots):
    # camera at the world origin at frame 0; mug box 0.1 x 0.2 x 0.6 at (1, 0, 0) turned 30 deg about z
    c = {"source": "Omni6DPose", "sequence": ROPE_SCENE, "entity": {"kind": "object", "id": "real-mug_001"},
         "times": [0.0], "operator": "distance_to_camera"}
    r = M.evaluate_contract(c, roots)
    q = rz(30).T @ np.array([-1.0, 0.0, 0.0])  # camera centre in box coordinates
    excess = np.maximum(np.abs(q) - np.array([0.05, 0.1, 0.3]), 0.0)
    assert r["value"] == pytest.approx(float(np.linalg.norm(excess)))
    r = M.evaluate_contract({**c, "operator": "dimension"}, roots)
    assert r["value"] == pytest.approx({"length": 0.1, "width": 0.2, "height": 0.6})


def test_scene_view_world_box_pair(roots):
    from resti_lib.sources.scannet import ScanNetScene

    view = R.SceneView("ScanNet", ScanNetScene(roots["scannet_root"], SN_SCENE))
    a = view.world_box("0")
    far = R.Instance("x", "x", box([5.5, 0.5, 0.5], [1, 1, 1]), "raw", np.ones(3), "")
    assert R.box_box_distance(a.box, far.box)[0] == pytest.approx(3.0)  # [0,2] to [5,6] along x


def _row(tight, axis_aligned, verdict="corrected"):
    from types import SimpleNamespace

    return (SimpleNamespace(verdict=verdict, defects=["value_mismatch"] if verdict == "corrected" else [],
                            evidence={"box_hypotheses": {"tight": 1.0, "axis_aligned": 1.2}}),
            {"tight": tight, "axis_aligned": axis_aligned})


def test_box_convention_majority_and_chance_agreement():
    from resti_lib.tasks import dimensional as D

    # three rows agree only with the axis-aligned box, one only with the tight box: axis-aligned rules
    rows = [_row(False, True), _row(False, True), _row(False, True), _row(True, False, "retained"),
            _row(True, True, "retained"), _row(False, False)]
    D._adjudicate_boxes(rows, {"mixed_share": 0.5})
    g = rows[0][0].evidence["box_convention"]
    assert (g["convention"], g["n_axis_aligned_only"], g["n_tight_only"], g["n_both"], g["n_neither"]) == \
        ("axis_aligned", 3, 1, 1, 1)
    assert [o.verdict for o, _ in rows] == ["re-contracted"] * 3 + ["retained", "retained", "corrected"]
    assert rows[0][0].defects == [] and rows[5][0].defects == ["value_mismatch"]
    # the other way round: a lone axis-aligned match in a tight-box task is a chance agreement ...
    rows = [_row(True, False, "retained") for _ in range(4)] + [_row(False, True)]
    D._adjudicate_boxes(rows, {"mixed_share": 0.25})  # the default of params/dimensional.yaml
    assert rows[4][0].verdict == "corrected" and "chance agreement" in rows[4][0].evidence["coincidence"]
    # ... unless the task is mixed (the minority has a quarter of the discriminating rows at least)
    rows = [_row(True, False, "retained") for _ in range(3)] + [_row(False, True)]
    D._adjudicate_boxes(rows, {"mixed_share": 0.25})  # the default of params/dimensional.yaml
    assert rows[3][0].evidence["box_convention"]["mixed"] and rows[3][0].verdict == "re-contracted"
    # no majority: each row keeps its own match
    rows = [_row(True, False, "retained"), _row(False, True)]
    D._adjudicate_boxes(rows, {"mixed_share": 0.25})  # the default of params/dimensional.yaml
    assert rows[0][0].evidence["box_convention"]["convention"] is None and rows[1][0].verdict == "re-contracted"


# ----------------------------------------------------------------------------- the mini-world


@pytest.fixture(scope="module")
def dim_run(miniworld, tmp_path_factory):
    return H.run_with_yaml(TASK, "dimensional", miniworld, tmp_path_factory.mktemp("dim_out"))


@pytest.fixture(scope="module")
def man(miniworld):
    return H.manifest(miniworld)


def test_miniworld_defects_recall_and_precision(dim_run, man, miniworld):
    amb = H.source_ambiguous_rows(dim_run, man, miniworld)
    assert amb == set()  # the generator's Waymo referents are unique in view (tests/test_synth.py)
    assert [m for m in H.defect_mismatches(dim_run, man) if m[0] not in amb] == []


def test_miniworld_verdicts_and_values(dim_run, man, miniworld):
    assert H.source_ambiguous_rows(dim_run, man, miniworld) == set()
    assert H.verdict_mismatches(dim_run, man) == []
    assert H.value_mismatches(dim_run, man) == []
    assert {o.source for o in dim_run.outcomes} == {"ScanNet", "Waymo", "Omni6DPose"}


def test_miniworld_box_convention_diagnosed(dim_run, man):
    """The mini-world's legacy ScanNet values use the annotation-frame axis-aligned box (manifest
    evidence ``legacy_box``); the task diagnoses that convention from the rows and re-contracts the
    rows that agree only under it, each with both values in its evidence."""
    scannet = [o for o in dim_run.outcomes if o.source == "ScanNet" and "box_convention" in o.evidence]
    assert scannet
    conv = scannet[0].evidence["box_convention"]
    assert all(o.evidence["box_convention"] == conv for o in scannet)
    assert conv["convention"] == "axis_aligned" and conv["n_tight_only"] == 0
    built = {m["row"] for m in man if m["task"] == "Dimensional Measurement"
             and m.get("evidence", {}).get("legacy_box") and m["expected_verdict"] == "re-contracted"}
    assert built and conv["n_axis_aligned_only"] == len(built)
    for o in dim_run.outcomes:
        if o.row in built:
            hyp = o.evidence["box_hypotheses"]
            assert o.verdict == "re-contracted" and "legacy_convention" in o.evidence
            # 0.1 mm: the raw-frame boxes go through the rigid inverse of the 6-decimal axisAlignment
            assert hyp["axis_aligned"] == pytest.approx(man[o.row]["evidence"]["axis_aligned_value_m"], abs=1e-4)
            assert hyp["tight"] == pytest.approx(man[o.row]["true_value"], abs=1e-4)
            assert abs(hyp["axis_aligned"] - hyp["tight"]) > 0.03


def test_miniworld_exclusions_carry_reasons_and_evidence(dim_run):
    assert dim_run.result.excluded and H.exclusion_problems(dim_run) == []
    for e in dim_run.result.excluded:
        ev = e["verification_evidence"]
        if e["reason_codes"] == ["ambiguous_instance"]:
            assert ev["n_instances"] >= 2 and "value_spread_m" in ev
        if e["reason_codes"] == ["not_visible_at_frame"]:
            assert "frame" in ev and ev["visibility"]


def test_miniworld_rewritten_questions_state_the_contract(dim_run):
    for row in dim_run.result.accepted:
        q = row["Question"]
        assert "(unit: " in q and row["Answer Detail"] == row["Candidates"][row["Answer"]]
        if "distance from the camera" in q:
            assert q.startswith("At t=")


def test_miniworld_no_significant_attack_and_valid_options(dim_run):
    assert H.significant_attacks(dim_run) == []
    assert H.structural_failures(dim_run) == []
