"""Helpers of the scalar-task tests (Dimensional, Displacement, Speed) on the mini-world."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from resti_lib import paths
from resti_lib.geometry import trajectory as G
from resti_lib.sources.waymo import WaymoSegment
from resti_lib.tasks.run import run_task


def miniworld_params(world: Path, output_dir: Path, **extra) -> dict:
    """Shared task parameters pointing at a generated mini-world (+ ``extra``)."""
    return {"legacy_benchmark": str(world / "legacy" / "qa.parquet"),
            "scannet_root": str(world / "scannet" / "scans"), "waymo_root": str(world / "waymo"),
            "omni6d_root": str(world / "omni6d"), "scannet_fps": 30, "omni6d_fps": 30, "video_map": "",
            "seed": 0, "output_dir": str(output_dir), **extra}


def manifest(world: Path) -> list[dict]:
    return [json.loads(line) for line in (world / "manifest.jsonl").read_text().splitlines()]


def run_with_yaml(task: str, name: str, world: Path, out: Path):
    """``run_task`` with the committed ``params/<name>.yaml`` on the mini-world."""
    own = yaml.safe_load((paths.PARAMS / f"{name}.yaml").read_text()) or {}
    return run_task(task, miniworld_params(world, out, **own))


def half_ulp_si(unit: str, decimals: int = 2) -> float:
    return 0.5 * 10.0 ** -decimals * {"m": 1.0, "cm": 0.01, "m/s": 1.0, "m/s²": 1.0}[unit]


def defect_mismatches(run, man: list[dict]) -> list[tuple]:
    """Rows whose detected defect set differs from the injected one: (row, missing, extra)."""
    out = []
    for o in run.outcomes:
        want, got = set(man[o.row]["defects"]), set(o.defects)
        if want != got:
            out.append((o.row, sorted(want - got), sorted(got - want)))
    return out


def verdict_mismatches(run, man: list[dict]) -> list[tuple]:
    return [(o.row, o.verdict, man[o.row]["expected_verdict"], o.reasons, man[o.row]["expected_reasons"])
            for o in run.outcomes
            if o.verdict != man[o.row]["expected_verdict"] or set(o.reasons) != set(man[o.row]["expected_reasons"])]


def value_mismatches(run, man: list[dict]) -> list[tuple]:
    """Accepted rows whose answer differs from the manifest's true value by more than half a printed unit."""
    out = []
    for o in run.outcomes:
        if o.verdict == "excluded" or man[o.row]["true_value"] is None:
            continue
        a = o.answer
        si = a.value * {"m": 1.0, "cm": 0.01, "m/s": 1.0, "m/s²": 1.0}[a.unit]
        if abs(si - float(man[o.row]["true_value"])) > half_ulp_si(a.unit) + 1e-9:
            out.append((o.row, si, man[o.row]["true_value"]))
    return out


def exclusion_problems(run) -> list:
    """Excluded records lacking a reason code or evidence."""
    return [e for e in run.result.excluded if not e["reason_codes"] or not e.get("verification_evidence")]


def significant_attacks(run) -> list[dict]:
    from resti_lib.options.attacks import attack_table

    table = attack_table(run.result.accepted)
    return table[table["significant"]].to_dict("records")


def unseen_subject_rows(run, man, world) -> set[int]:
    """Rows whose subject the generator took although the camera never sees it.

    The generator falls back to unseen movers when none is in view; the audit requires the
    subject in view (ReSTI v5: out-of-frustum targets are excluded). Checked here independently:
    the manifest's object centre never projects into the camera image during the interval.
    """

    out = set()
    for o in run.outcomes:
        if o.reasons != ["not_visible_at_frame"] or o.source != "Waymo":
            continue
        m = man[o.row]
        seg = WaymoSegment(world / "waymo", m["sequence"])
        tr = seg.object_track(m["contract"]["entity"]["id"])
        t0, t1 = m["contract"]["times"]
        sel = (tr.times >= t0 - 1e-3) & (tr.times <= t1 + 1e-3)
        cam = seg.camera_track(m["camera"])
        Tc, _ = G.pose_at(cam, tr.times[sel], "linear", 1e-6)
        p = np.einsum("nji,nj->ni", Tc[:, :3, :3], tr.positions[sel] - Tc[:, :3, 3])  # R^T (x - c)
        cal = seg.camera_calibration(m["camera"])
        k = cal["intrinsics"]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = k["f_u"] * p[:, 0] / p[:, 2] + k["c_u"]
            v = k["f_v"] * p[:, 1] / p[:, 2] + k["c_v"]
        inside = (p[:, 2] > 0) & (u >= 0) & (u < cal["width"]) & (v >= 0) & (v < cal["height"])
        assert not inside.any(), f"row {o.row}: the subject is in view, yet excluded"
        assert m["expected_verdict"] != "excluded"
        out.add(o.row)
    return out
