"""Loaders: legacy qa.parquet and ReSTI-schema releases, strict validation naming file/row/field."""

import json

import pandas as pd
import pytest

from resti_lib.errors import InputError
from resti_lib.io.benchmark import legacy_row_keys, load_legacy, load_release, parse_key
from resti_lib.tasks import names
from tests.helpers import row, write_legacy, write_release


@pytest.mark.parametrize("as_", ["json", "dict"])
def test_legacy_candidates_json_string_or_dict(tmp_path, as_):
    rows = [row(rid=0), row(rid=1, answer="C")]
    if as_ == "dict":
        # a dict column round-trips through parquet as a struct
        p = tmp_path / "qa.parquet"
        pd.DataFrame.from_records(rows).to_parquet(p)
    else:
        p = write_legacy(rows, tmp_path / "qa.parquet")
    df, problems = load_legacy(p)
    assert problems == []
    assert df.loc[1, "Candidates"]["C"] == "3.00m"
    assert list(df["row"]) == [0, 1]
    k = parse_key(df.loc[0, "Legacy Row Key"])
    assert k["source"] == "ScanNet" and k["video"] == "scene0900_00.mp4" and len(k["uid"]) == 16


def test_keys_unique_even_for_identical_rows():
    keys = legacy_row_keys([row(), row()])
    assert len(set(keys)) == 2


@pytest.mark.parametrize("mutate,field", [
    (lambda r: r.update(Task="3D Video Grounding Plus"), "Task"),
    (lambda r: r.update(Source="Kitti"), "Source"),
    (lambda r: r["Candidates"].pop("E"), "Candidates"),
    (lambda r: r["Candidates"].update(F="6.00m"), "Candidates"),
    (lambda r: r.update(Answer="F"), "Answer"),
    (lambda r: r.update(time_start=float("nan")), "time_start"),
    (lambda r: r.update(time_start=6.0, time_end=5.0), "time_end"),
])
def test_legacy_bad_rows_name_file_row_field(tmp_path, mutate, field):
    rows = [row(rid=0), row(rid=1), row(rid=2)]
    mutate(rows[1])
    p = write_legacy(rows, tmp_path / "qa.parquet")
    with pytest.raises(InputError) as e:
        load_legacy(p, known_tasks=names())  # the tasks a row may name: the registry's
    err = e.value
    assert err.file.endswith("qa.parquet") and err.row == 1 and err.field == field
    # non-strict keeps every row and records the problem for row 1
    df, problems = load_legacy(p, strict=False, known_tasks=names())
    assert len(df) == 3 and {pr.row for pr in problems} == {1}


def test_legacy_malformed_candidates_json(tmp_path):
    rows = [row(rid=0), row(rid=1)]
    recs = [dict(r, Candidates=json.dumps(r["Candidates"])) for r in rows]
    recs[1]["Candidates"] = '{"A": "1.00m", "B": '
    p = tmp_path / "qa.parquet"
    pd.DataFrame.from_records(recs).to_parquet(p)
    with pytest.raises(InputError, match="Candidates is not valid JSON") as e:
        load_legacy(p)
    assert e.value.row == 1 and e.value.field == "Candidates"


def test_legacy_missing_column(tmp_path):
    p = tmp_path / "qa.parquet"
    pd.DataFrame.from_records([{k: v for k, v in row().items() if k != "Answer Detail"}]).to_parquet(p)
    with pytest.raises(InputError, match="missing column") as e:
        load_legacy(p)
    assert e.value.field == "Answer Detail"


def test_release_truncated_jsonl_line(tmp_path):
    folder = write_release([row(rid=0), row(rid=1)], [], tmp_path / "rel")
    text = (folder / "resti.jsonl").read_text()
    (folder / "resti.jsonl").write_text(text[: len(text) - 40])
    with pytest.raises(InputError, match="line 2 is not valid JSON") as e:
        load_release(folder)
    assert e.value.row == "line 2"


def test_release_duplicate_ids(tmp_path):
    folder = write_release([row(rid=0), row(rid=1)], [], tmp_path / "rel")
    lines = (folder / "resti.jsonl").read_text().splitlines()
    second = json.loads(lines[1])
    second["ReSTI ID"] = "resti-test-0"
    (folder / "resti.jsonl").write_text(lines[0] + "\n" + json.dumps(second) + "\n")
    with pytest.raises(InputError, match="appears 2 times") as e:
        load_release(folder)
    assert e.value.row == "resti-test-0" and e.value.field == "ReSTI ID"


def test_release_parquet_equals_jsonl(tmp_path):
    from resti_lib.io.benchmark import rows_to_parquet_bytes

    folder = write_release([row(rid=0), row(rid=1, answer="D")], [], tmp_path / "rel")
    a = load_release(folder / "resti.jsonl").accepted
    (tmp_path / "resti.parquet").write_bytes(rows_to_parquet_bytes(a.to_dict("records")))
    b = load_release(tmp_path / "resti.parquet").accepted
    assert a.to_dict("records") == b[list(a.columns)].to_dict("records")
