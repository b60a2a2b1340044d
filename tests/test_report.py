"""The HTML index: every link and image resolves on disk; real-data params: one message for all."""

import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest

from resti_lib.report.index import write_index
from resti_lib.sources.context import check_real_params


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs = []

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k in ("href", "src") and v:
                self.refs.append(v)


def links_of(html_path: Path) -> list[str]:
    p = _Links()
    p.feed(html_path.read_text(encoding="utf-8"))
    return p.refs


def assert_links_resolve(index: Path) -> int:
    refs = [r for r in links_of(index) if not re.match(r"^[a-z]+:", r) and not r.startswith("#")]
    missing = [r for r in refs if not (index.parent / r.split("#", 1)[0]).exists()]  # a file, then its anchor
    assert not missing, f"unresolved links in {index}: {missing}"
    return len(refs)


def test_index_links_resolve(tmp_path):
    out = tmp_path / "outputs"
    (out / "report" / "notebooks").mkdir(parents=True)
    (out / "report" / "notebooks" / "01_grounding.html").write_text("<html></html>")
    (out / "tables").mkdir()
    (out / "tables" / "coverage_by_task.md").write_text("| a |\n")
    (out / "tables" / "coverage_by_task.csv").write_text("a\n")
    (out / "figures").mkdir()
    (out / "figures" / "99_audit_overview.png").write_bytes(b"\x89PNG\r\n")
    (out / "release").mkdir()
    (out / "release" / "resti.jsonl").write_text("{}\n")
    index = write_index(out)
    n = assert_links_resolve(index)
    assert n == 6  # notebook, release file, table md + csv, figure link + its img
    assert "99_audit_overview.png" in index.read_text()


def test_real_params_list_everything_missing(tmp_path):
    params = {"legacy_benchmark": str(tmp_path / "nope.parquet"), "scannet_root": str(tmp_path / "scans"),
              "waymo_root": "", "omni6d_root": str(tmp_path)}
    problems = check_real_params(params)
    text = "\n".join(problems)
    assert "legacy_benchmark" in text and "scannet_root" in text and "waymo_root: not given" in text
    assert "ROPE" in text  # omni6d_root exists but lacks ROPE/ and Meta/


def test_run_with_bad_paths_exits_2_with_one_message(tmp_path):
    bad = tmp_path / "real.yaml"
    bad.write_text(f"world_dir: ''\nlegacy_benchmark: {tmp_path}/qa.parquet\nscannet_root: {tmp_path}/s\n"
                   f"waymo_root: {tmp_path}/w\nomni6d_root: {tmp_path}/o\nstages: []\n")
    r = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "run", "--params", str(bad)], capture_output=True,
                       text=True)
    assert r.returncode == 2
    for key in ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root"):
        assert key in r.stderr


# ------------------------------------------------------------------ header, tables, figures

def test_run_context_date_only_from_source_date_epoch(monkeypatch):
    from resti_lib.run.runinfo import run_context

    cfg = {"world_dir": "outputs/miniworld", "world_seed": 3, "legacy_benchmark": "outputs/miniworld/legacy/qa.parquet",
           "output_dir": "outputs", "stages": []}
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    ctx = run_context(cfg, {})
    assert "date" not in ctx  # no clock: reruns stay byte-identical
    assert ctx["input"] == {"kind": "mini-world", "synthetic": True, "seed": 3, "world_dir": "outputs/miniworld"}
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "86400")
    assert run_context(cfg, {})["date"] == "1970-01-02T00:00:00Z"  # one day after the epoch


def test_run_context_real_input_and_params_digest():
    from resti_lib.run.runinfo import run_context, stage_params_digest

    cfg = {"world_dir": "", "legacy_benchmark": "/data/qa.parquet", "scannet_root": "/data/scans",
           "output_dir": "outputs/real", "jobs": 2, "stages": [{"notebook": "03_dimensional"}]}
    ctx = run_context(cfg, {"03_dimensional": stage_params_digest({"decimals": 2, "output_dir": "x"})})
    assert ctx["input"] == {"kind": "real data", "synthetic": False, "legacy_benchmark": "/data/qa.parquet",
                            "scannet_root": "/data/scans"}
    # where outputs go and how many jobs run do not change the digest; a parameter does
    moved = {**cfg, "output_dir": "elsewhere", "jobs": 1}
    same = run_context(moved, {"03_dimensional": stage_params_digest({"decimals": 2, "output_dir": "y"})})
    other = run_context(cfg, {"03_dimensional": stage_params_digest({"decimals": 3, "output_dir": "x"})})
    assert same["params_digest"] == ctx["params_digest"] != other["params_digest"]


def test_shown_tables_format_percentages_and_drop_positions():
    from resti_lib.io.tables import formatted, to_html

    df = pd.DataFrame({"category": ["a", "b", "c"], "reports": [83, 13, 4], "share": [0.83, 0.13, 0.04],
                       "p_value": [0.000123456, 0.5, 1.0]}).sort_values("reports", ascending=True)
    f = formatted(df)
    assert list(f.columns) == ["category", "reports", "share", "p_value"]  # no index column
    assert list(f["share"]) == ["4.0%", "13.0%", "83.0%"] and list(f["p_value"]) == ["1", "0.5", "0.000123"]
    assert "<th>share</th>" in to_html(df) and ">83.0%<" in to_html(df)
    counts = pd.Series([5, 2], index=pd.Index(["ambiguous_instance", "grouped_referent"], name="reason"))
    assert list(formatted(counts.to_frame("rows")).columns) == ["reason", "rows"]  # a named index is data


def test_write_table_shows_percent_and_keeps_raw_csv(tmp_path):
    from resti_lib.io.tables import write_table

    write_table(pd.DataFrame({"defect": ["x"], "recall": [0.875]}), tmp_path / "t")
    assert "87.5%" in (tmp_path / "t.md").read_text() and "87.5\\%" in (tmp_path / "t.tex").read_text()
    assert (tmp_path / "t.csv").read_text() == "defect,recall\nx,0.875\n"


def test_key_detail_breakdown_by_cause():
    from resti_lib.report.statistics import key_detail_breakdown
    from tests.helpers import row

    five = {"A": "1.00m", "B": "2.00m", "C": "3.00m", "D": "4.00m", "E": "5.00m"}
    pose = ('{"tx":1.00,"ty":2.00,"tz":3.00,"r11":1.0,"r12":0.0,"r13":0.0,"r21":0.0,"r22":1.0,"r23":0.0,'
            '"r31":0.0,"r32":0.0,"r33":1.0}')
    pose2 = pose.replace('"tz":3.00', '"tz":3.50')  # 0.5 m off, beyond the rounding of 0.005
    rows = [
        row(cands=five, answer="B", detail="2.00m"),                    # keyed == detail: not counted
        row(cands=five, answer="B", detail="3.10m"),                    # 2.00 vs 3.10: scalar
        row(cands=five, answer="B", detail="2.0m"),                     # same value, coarser: rounding
        row(cands=five, answer="B", detail="2.03m"),                    # 2.00 vs 2.03: scalar
        row(cands=five, answer="B", detail="Front"),                    # scalar vs label: format
        row(task="Pose Estimation", cands={**five, "B": pose}, answer="B", detail=pose2),  # structured
    ]
    t = key_detail_breakdown(pd.DataFrame(rows))
    by = {c.split(" ")[0].rstrip(","): n for c, n in zip(t["cause"], t["rows"])}
    # 2.00 vs 2.03: the coarser printed place is 0.01 m, half of it 0.005 < 0.03 -> scalar disagreement
    assert by["structured"] == 1 and by["scalar"] == 2 and by["incompatible"] == 1 and by["same"] == 1
    # the report's definition first: every keyed text that is not the detail text (5 rows, rounding in);
    # ours last: the 4 whose values disagree or cannot be compared
    assert t.iloc[0]["cause"].startswith("mismatches, the ReSTI report's definition") and t.iloc[0]["rows"] == 5
    assert t.iloc[-1]["cause"].startswith("mismatches, our definition") and t.iloc[-1]["rows"] == 4
    same = t[t["cause"].str.startswith("same")].iloc[0]
    assert bool(same["ReSTI report's definition"]) and not bool(same["ours"])


def test_exclusions_recoverable_or_structural():
    from resti_lib.report.statistics import exclusion_class_table

    # recoverable: an ambiguous or unmatched referent; structural: a defective statement (an object not
    # visible at the asked frame is one, whatever else the row says); a copy of a row is neither
    ex = [{"task": "Dimensional Measurement", "reason_codes": ["ambiguous_instance"]},
          {"task": "Dimensional Measurement", "reason_codes": ["not_visible_at_frame", "undefined_dimension"]},
          {"task": "Dimensional Measurement", "reason_codes": ["grouped_referent"]},
          {"task": "Pose Estimation", "reason_codes": ["premise_equals_target"]},
          {"task": "Displacement & Path Length", "reason_codes": ["zero_length_interval", "ambiguous_subject"]},
          {"task": "Pose Estimation", "reason_codes": ["duplicate_row"]}]
    t = exclusion_class_table(ex).set_index("class")
    assert t.loc["recoverable", "rows"] == 2 and t.loc["structural", "rows"] == 3 and t.loc["other", "rows"] == 1
    assert t.loc["recoverable", "share"] == pytest.approx(2 / 6)
    assert t.loc["structural", "by task"] == "Dimensional Measurement 2, Pose Estimation 1"


def test_one_exclusion_rule_for_ours_and_v5():
    """Every v5 verdict of the glossary names one of our reason codes whose class is the verdict's."""
    from resti_lib.defects import REASONS
    from resti_lib.report.exclusions import glossary_spec
    from resti_lib.report.statistics import exclusion_class

    for verdict, entry in glossary_spec()["verdicts"].items():
        assert entry["ours"] in REASONS, verdict
        assert exclusion_class([entry["ours"]]) == entry["class"], verdict


def test_v5_exclusion_split_by_the_stated_rule():
    from resti_lib.report.exclusions import exclusion_glossary, exclusion_split

    # hand-built: two verdicts of each class, one unverified row (structural by the rule), one unknown verdict
    ex = [{"reason_codes": ["waymo_object_track_not_yet_reconstructed"],
           "verification_verdict": "exclusion_confirmed_object_match_ambiguous"},
          {"reason_codes": ["scannet_source_reconstruction_not_implemented"],
           "verification_verdict": "exclusion_confirmed_no_source_instance"},
          {"reason_codes": ["scannet_source_reconstruction_not_implemented"],
           "verification_verdict": "exclusion_confirmed_group_referent_not_single_instance"},
          {"reason_codes": ["waymo_object_track_not_yet_reconstructed"],
           "verification_verdict": "exclusion_confirmed_degenerate_time_window"},
          {"reason_codes": ["excluded_unresolved_grounding_target"]},
          {"reason_codes": ["something_new"], "verification_verdict": "exclusion_confirmed_new"}]
    t = exclusion_split(ex, paper={"recoverable": 2, "structural": 3}).set_index("class")
    assert t.loc["recoverable", "rows"] == 2 and t.loc["structural", "rows"] == 3 and t.loc["unknown", "rows"] == 1
    assert t.loc["structural", "ReSTI report"] == 3
    g = exclusion_glossary(ex).set_index("code")
    assert g.loc["scannet_source_reconstruction_not_implemented", "rows"] == 2
    assert g.loc["something_new", "meaning"] == "(not in the glossary)"
    assert g.loc["exclusion_confirmed_no_source_instance", "ours"].startswith("no_source_instance: ")
    assert g.loc["(no verification verdict)", "rows"] == 1


def test_pooled_scalar_attacks_median_pick():
    from resti_lib.report.statistics import pooled_scalar_attacks
    from tests.helpers import row

    # 10 scalar rows whose answer is always the median candidate (C of 1..5), across two tasks,
    # and one label row that the pool leaves out
    five = {"A": "1.00m", "B": "2.00m", "C": "3.00m", "D": "4.00m", "E": "5.00m"}
    rows = [row(task=t, cands=five, answer="C", rid=i) for i, t in
            enumerate(["Dimensional Measurement"] * 6 + ["Displacement & Path Length"] * 4)]
    rows.append(row(task="Spatial Relation", cands={k: v for k, v in zip("ABCDE", ["Front", "Back", "Left",
                                                                                       "Right", "Above"])},
                    answer="A", detail="Front", rid=99))
    t = pooled_scalar_attacks(pd.DataFrame(rows)).set_index("attack")
    assert t.loc["median", "rows"] == 10 and t.loc["median", "hits"] == 10 and t.loc["median", "accuracy"] == 1.0
    assert t.loc["min", "hits"] == 0
    assert t.index[0] in ("median", "nearest_mean", "medoid", "constant_letter")  # strongest first


def test_figure_registry_order_and_captions(tmp_path):
    from resti_lib.report.figures import figure_specs, ordered_figures

    for name in ("07_trajectory_paths", "zz_other", "99_attacks_after", "99_audit_overview",
                 "00_answer_interface_attacks_resti_v5"):
        (tmp_path / f"{name}.png").write_bytes(b"\x89PNG\r\n")
    order = [(p.stem, spec.section if spec else None) for p, spec in ordered_figures(tmp_path)]
    assert order == [("99_audit_overview", "Overview"), ("00_answer_interface_attacks_resti_v5", "Answer interface"),
                     ("99_attacks_after", "Answer interface"), ("07_trajectory_paths", "Tasks"), ("zz_other", None)]
    assert all(len(s.caption) > 40 for s in figure_specs())


@pytest.mark.slow
def test_default_run_makes_only_registered_figures(main_run):
    from resti_lib.report.figures import spec_for

    pngs = sorted(p.stem for p in (main_run.out / "figures").glob("*.png"))
    assert "99_audit_overview" in pngs
    assert [p for p in pngs if spec_for(p) is None] == []
    index = (main_run.out / "report" / "index.html").read_text()
    assert index.index("99_audit_overview.png") < min(index.index(f"{p}.png") for p in pngs if p != "99_audit_overview")


def test_index_header_and_headline(main_run):
    index = (main_run.out / "report" / "index.html").read_text()
    head, rest = index.split("<section id=\"headline\">", 1)
    for text in ("Input: the synthetic mini-world", "Params digest", "Code version", "Packages", "Date"):
        assert text in head
    assert "Our release" in rest and "Verdict shares" in rest and "Defect categories" in rest
    assert rest.index("Answer-interface audit of the reference release") < rest.index("Self-test on the mini-world")
    for stem in ("key_detail_breakdown", "exclusion_classes", "legacy_scalar_attacks"):
        assert f"tables/{stem}.md" in index  # shown on the page, with its files
