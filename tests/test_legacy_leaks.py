"""The legacy mini-world carries the option leaks the ReSTI report measured on STI-Bench (the median
candidate is the answer on 46.9% of the legacy scalar rows; the ±7.5°/±15° grid; Waymo Orientation
answers the smallest candidate), recorded in the manifest, and the repair removes them."""

from __future__ import annotations

import json
from collections import Counter

import pandas as pd
import pytest

from resti_lib import values as V
from resti_lib.errors import InputError

ORI = "Ego-Centric Orientation"


def _median_hits(rows: list[dict]) -> tuple[float, int]:
    """(rows whose keyed letter is the median of five scalar candidates, rows with five scalar candidates),
    counted by sorting the parsed values; a median value printed twice (a duplicate) is a tie of the two
    letters, worth half a hit when the key is one of them."""
    hits = n = 0
    for r in rows:
        cands = r["Candidates"] if isinstance(r["Candidates"], dict) else json.loads(r["Candidates"])
        try:
            vals = {k: V.parse(s) for k, s in cands.items()}
        except InputError:
            continue
        if len(vals) != 5 or not all(isinstance(v, V.Scalar) for v in vals.values()):
            continue
        mid = sorted(v.si for v in vals.values())[2]
        tied = [k for k, v in vals.items() if abs(v.si - mid) < 1e-12]
        n += 1
        hits += (r["Answer"] in tied) / len(tied)
    return hits, n


def _legacy(world) -> list[dict]:
    return pd.read_parquet(world / "legacy" / "qa.parquet").to_dict("records")


def _manifest(world) -> list[dict]:
    return [json.loads(x) for x in (world / "manifest.jsonl").read_text().splitlines()]


def test_default_world_median_pick_near_the_report(miniworld):
    from resti_lib.report.statistics import pooled_scalar_attacks

    rows = _legacy(miniworld)
    hits, n = _median_hits(rows)
    assert 0.42 <= hits / n <= 0.52, (hits, n)  # the report: 46.9% of 1,129 legacy scalar rows
    t = pooled_scalar_attacks(pd.DataFrame(rows).assign(Candidates=lambda d: d["Candidates"].map(json.loads)))
    med = t.set_index("attack").loc["median"]
    assert (med["hits"], med["rows"]) == (hits, n) and bool(med["significant"])


def test_manifest_records_the_option_construction(miniworld):
    man = _manifest(miniworld)
    rows = _legacy(miniworld)
    by = Counter((m["task"], m["source"], m["legacy_options"]["construction"]) for m in man)
    assert by[(ORI, "ScanNet", "angle_grid")] == sum(m["task"] == ORI and m["source"] == "ScanNet" for m in man)
    assert by[(ORI, "Waymo", "angle_smallest")] == sum(m["task"] == ORI and m["source"] == "Waymo" for m in man)
    scalar = [m for m in man if m["legacy_options"]["construction"] in ("balanced", "random")]
    assert 0.8 <= sum(m["legacy_options"]["construction"] == "balanced" for m in scalar) / len(scalar) <= 0.97
    for m, r in zip(man, rows):
        rank = m["legacy_options"]["answer_rank"]
        if m["legacy_options"]["construction"] == "angle_smallest":
            assert rank == 1
        if m["legacy_options"]["construction"] == "angle_grid":
            assert rank == 3
        if rank is not None and "key_detail_mismatch" not in m["defects"] and \
                "duplicate_options_numeric" not in m["defects"]:
            cands = json.loads(r["Candidates"])
            vals = sorted(V.parse(s).si for s in cands.values())
            assert vals.index(V.parse(cands[r["Answer"]]).si) + 1 == rank  # the keyed answer's rank, by hand


@pytest.mark.shared
def test_scale_one_orientation_median_pick_is_significant_before_repair(tmp_path, resti_v5_dir):
    """At scale 1 the legacy rows have STI-Bench's composition (104 ScanNet and 81 Waymo Orientation rows):
    the Orientation median pick is far above chance, Holm-significant in the option-only table."""
    from resti_lib.options.attacks import attack_table
    from resti_lib.synth import generate
    from resti_lib.tasks import interface

    generate(tmp_path, seed=0, scale=1, resti_v5_dir=resti_v5_dir)
    rows = [r for r in _legacy(tmp_path) if r["Task"] == ORI]
    assert Counter(r["Source"] for r in rows) == {"ScanNet": 104, "Waymo": 81}
    hits, n = _median_hits(rows)
    assert n == 185 and hits / n >= 0.35  # chance is 20%
    recs = [dict(r, Candidates=json.loads(r["Candidates"])) for r in rows]
    t = attack_table(recs, iface=interface(), families=["option"])
    med = t[(t["attack"] == "median") & (t["source"] == "ALL")].iloc[0]
    assert med["hits"] == hits and bool(med["significant"])
    hits_all, n_all = _median_hits(_legacy(tmp_path))
    assert 0.42 <= hits_all / n_all <= 0.52, (hits_all, n_all)  # the report: 46.9% of 1,129


def test_repair_removes_the_median_leak(main_run):
    """Before: the legacy rows' pooled median pick is significant; after: the release's is not, and its
    Orientation median pick is not either (counted here from the release rows)."""
    ba = pd.read_csv(main_run.out / "tables" / "scalar_attacks_before_after.csv").set_index("attack")
    assert bool(ba.loc["median", "significant before"]) and not bool(ba.loc["median", "significant after"])
    acc = [json.loads(x) for x in (main_run.out / "release" / "resti.jsonl").read_text().splitlines()]
    hits, n = _median_hits(acc)
    assert (hits, n) == (ba.loc["median", "hits after"], ba.loc["median", "rows after"])
    ori_hits, ori_n = _median_hits([r for r in acc if r["Task"] == ORI])
    t = pd.read_csv(main_run.out / "tables" / "attacks_release.csv")
    med = t[(t["task"] == ORI) & (t["source"] == "ALL") & (t["attack"] == "median")].iloc[0]
    assert med["hits"] == ori_hits and med["picked"] == ori_n and not bool(med["significant"])
