"""One attack number: ``resti attack``, the report's headline and the run's closing summary print the
same counts for the same folder (the suite of :func:`resti_lib.release.audit.attack_release`)."""

from __future__ import annotations

import html
import re

import pandas as pd
import pytest

from resti_lib.options.attacks import attack_table, select
from resti_lib.release.audit import SUITE, attack_counts, attack_release, suite_command
from resti_lib.tasks import interface
from tests.conftest import run_cli
from tests.helpers import row, write_release

COUNTS = re.compile(r"(\d+) of (\d+) task/source cells have a Holm-significant blind attack(?:\*\*)? "
                    r"\((\d+) of (\d+) tests\)")


def _counts(text: str) -> list[tuple[int, ...]]:
    return [tuple(int(x) for x in m.groups()) for m in COUNTS.finditer(html.unescape(text))]


def _by_hand(csv) -> tuple[int, int, int, int]:
    """(significant cells, cells, significant tests, tests) counted from the table's CSV text."""
    t = pd.read_csv(csv)
    sig = t["significant"].astype(str) == "True"
    cells = set(zip(t["task"], t["source"]))
    return len(set(zip(t.loc[sig, "task"], t.loc[sig, "source"]))), len(cells), int(sig.sum()), len(t)


def test_attack_counts_by_hand():
    t = pd.DataFrame({"task": ["T1", "T1", "T1", "T2", "T2"], "source": ["S", "S", "ALL", "S", "ALL"],
                      "significant": [True, False, True, False, False]})
    c = attack_counts(t)
    assert (c.tests, c.significant, c.cells, c.significant_cells) == (5, 2, 4, 2)
    assert c.sentence() == "2 of 4 task/source cells have a Holm-significant blind attack (2 of 5 tests)"
    # read back from a CSV the significant column is text
    assert attack_counts(t.assign(significant=t["significant"].map(str))) == c
    assert attack_counts(None).tests == 0


def test_suite_command_names_only_what_differs():
    assert suite_command("outputs/release", SUITE) == "resti attack outputs/release"
    assert suite_command("a b", {"families": ["option"], "fast": True, "alpha": 0.01}) == \
        "resti attack 'a b' --families option --fast --alpha 0.01"


def test_attack_release_is_the_suite_on_the_readable_rows(tmp_path):
    rows = [row(rid=i, answer="ABCDE"[i % 5], cands={k: f"{(j + 1) * (i + 1) / 10:.2f}m"
                                                     for j, k in enumerate("ABCDE")}) for i in range(15)]
    for r in rows:
        r["Answer Detail"] = r["Candidates"][r["Answer"]]
    bad = dict(rows[3], Candidates={**rows[3]["Candidates"], "C": "12..5m"})
    rel = write_release(rows[:3] + [bad] + rows[4:], [], tmp_path / "rel")
    run = attack_release(rel, fast=True)
    assert len(run.skipped) == 1 and "Candidates.C" in next(iter(run.skipped.values()))
    # a second path: the attack table of the 14 readable rows with every family but the learned ones
    direct = attack_table(rows[:3] + rows[4:], iface=interface(), families="all", attacks=select(None, fast=True))
    pd.testing.assert_frame_equal(run.table.reset_index(drop=True), direct.reset_index(drop=True))
    assert run.command("rel") == "resti attack rel --fast"


def test_attack_summary_and_report_print_the_same_counts(main_run):
    """Our release: the closing summary of the run, the report's headline and `resti attack` agree."""
    rel = main_run.out / "release"
    by_hand = _by_hand(main_run.out / "tables" / "attacks_release.csv")
    r = run_cli(["attack", str(rel), "--headline"])
    assert r.returncode == 0, r.stderr[-2000:]
    cli = _counts(r.stdout.splitlines()[0])
    summary = [ln for ln in main_run.stdout.splitlines() if "blind attacks on our release" in ln]
    index = (main_run.out / "report" / "index.html").read_text(encoding="utf-8")
    ours = index.split("Blind attacks on our release", 1)[1].split("Answer-interface audit of the reference", 1)[0]
    assert cli == [by_hand]
    assert _counts(summary[0]) == [by_hand]
    assert _counts(ours)[:1] == [by_hand]


@pytest.mark.shared
def test_reference_counts_agree_with_resti_attack(main_run, resti_v5_dir):
    """The reference release (ReSTI v5): notebook 00's table, the summary, the headline and `resti attack`
    on the same folder count the same; the headline states the verify result with its failing rows."""
    by_hand = _by_hand(main_run.out / "answer_interface" / "attacks_resti_v5.csv")
    r = run_cli(["attack", str(resti_v5_dir), "--headline"])
    assert r.returncode == 0, r.stderr[-2000:]
    assert _counts(r.stdout.splitlines()[0]) == [by_hand]
    summary = [ln for ln in main_run.stdout.splitlines() if "reference release" in ln]
    assert _counts(summary[0]) == [by_hand]
    index = (main_run.out / "report" / "index.html").read_text(encoding="utf-8")
    ref = index.split("Answer-interface audit of the reference", 1)[1]
    assert _counts(ref)[:1] == [by_hand]
    v = run_cli(["verify", str(resti_v5_dir)])
    failing = dict(re.findall(r"FAIL\s+(\S+) \((\d+) failing", v.stdout))
    assert v.returncode == 1 and failing  # ReSTI v5 fails verify (separation and plausibility)
    for check, n in failing.items():
        assert f"<code>{check}</code> {n} rows" in ref
    assert "verify_failures_resti_v5.md" in ref
    fails = pd.read_csv(main_run.out / "answer_interface" / "verify_failures_resti_v5.csv")
    assert fails.groupby("check").size().to_dict() == {k: int(n) for k, n in failing.items()}
