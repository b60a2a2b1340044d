"""The HTML index: every link and image resolves on disk; real-data params: one message for all."""

import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

from resti_lib.report import write_index
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
    missing = [r for r in refs if not (index.parent / r).exists()]
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
    r = subprocess.run([sys.executable, "-m", "resti_lib.cli", "run", "--params", str(bad)], capture_output=True,
                       text=True)
    assert r.returncode == 2
    for key in ("legacy_benchmark", "scannet_root", "waymo_root", "omni6d_root"):
        assert key in r.stderr
