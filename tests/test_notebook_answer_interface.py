"""notebooks/00_answer_interface.ipynb executed through papermill on a small hand-built release."""

import json

import pytest

from resti_lib import paths
from resti_lib.run.notebooks import NotebookError, run_notebook
from tests.helpers import row, write_release

pytestmark = pytest.mark.notebook

NB = paths.NOTEBOOKS / "00_answer_interface.ipynb"


def _release(tmp_path, n=12):
    rows = [row(rid=i, answer="ABCDE"[i % 5],
                cands={k: f"{(j + 1) * (i + 1) / 10:.2f}m" for j, k in enumerate("ABCDE")})
            for i in range(n)]
    for r in rows:
        r["Answer Detail"] = r["Candidates"][r["Answer"]]
    return write_release(rows, [], tmp_path / "rel")


def test_notebook_runs_and_writes_tables(tmp_path):
    rel = _release(tmp_path)
    out = tmp_path / "ai"
    run = run_notebook(NB, {"release_path": str(rel), "audit_dir": str(out), "figure_dir": str(tmp_path / "f")},
                       out_dir=tmp_path / "nb", html_dir=tmp_path / "html")
    assert run.html.exists() and run.html.stat().st_size > 10_000
    v = json.loads((out / "validation_release.json").read_text())
    assert v["accepted_rows"] == 12 and v["passed"]
    csv = (out / "attacks_release.csv").read_text().splitlines()
    assert csv[0].startswith("attack,family,task,source,n_rows,")
    head = (out / "attacks_release_headline.csv").read_text().splitlines()
    assert head[0].startswith("task,source,n_rows,significant,attack,")
    assert list((tmp_path / "f").glob("*.png"))


def test_failing_cell_names_notebook_and_cell(tmp_path):
    rel = _release(tmp_path)
    lines = (rel / "resti.jsonl").read_text().splitlines()
    r0 = json.loads(lines[0])
    # an unreadable row: the audit stops in its cell (a failing check is a finding, reported, not a stop)
    (rel / "resti.jsonl").write_text("\n".join([json.dumps(r0)[:-5]] + lines[1:]) + "\n")
    with pytest.raises(NotebookError) as e:
        run_notebook(NB, {"release_path": str(rel), "audit_dir": str(tmp_path / "ai"),
                          "figure_dir": str(tmp_path / "f")}, out_dir=tmp_path / "nb", html_dir=tmp_path / "h")
    msg = str(e.value)
    assert "00_answer_interface.ipynb" in msg and "code cell" in msg and "InputError" in msg


def test_unknown_parameter_is_an_error(tmp_path):
    with pytest.raises(NotebookError, match="unknown parameter"):
        run_notebook(NB, {"alpah": 0.1}, out_dir=tmp_path, html_dir=tmp_path)
