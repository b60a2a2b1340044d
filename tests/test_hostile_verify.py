"""`resti verify` never passes what it did not check: null ids, malformed keys, impossible values,
empty releases, digests of absent files and a release.json without counts fail or are reported as
not checked; SHA256SUMS entries stay inside the release folder and only regular files are opened.
Damaged copies of the public v5 release and of hand-built releases are made in tmp_path."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from resti_lib.release.verify import format_text, verify_path
from tests.helpers import row, seal_release, write_release


@pytest.fixture
def v5(resti_v5_dir, tmp_path) -> tuple[Path, list[dict]]:
    dst = tmp_path / "v5"
    shutil.copytree(resti_v5_dir, dst)
    dst.chmod(0o755)
    for p in dst.iterdir():
        p.chmod(0o644)
    rows = [json.loads(line) for line in (dst / "resti.jsonl").read_text(encoding="utf-8").splitlines()]
    return dst, rows


def _put(dst: Path, rows: list[dict]) -> None:
    (dst / "resti.jsonl").write_text("".join(json.dumps(r, ensure_ascii=False) + "\n" for r in rows),
                                     encoding="utf-8")


def _failing(v: dict) -> dict:
    return {k: c["failing"] for k, c in v["checks"].items() if c["status"] == "fail"}


def _first(rows, task):
    return next(i for i, r in enumerate(rows) if r["Task"] == task)


def test_null_ids_fail(v5):
    dst, rows = v5
    rows[3]["ReSTI ID"] = None
    rows[8]["Legacy Row Key"] = None
    rows[9]["ReSTI ID"] = ""
    _put(dst, rows)
    v = verify_path(dst)
    assert not v["passed"]
    failing = set(v["checks"]["row_ids"]["failing"])
    # rows are named by the id they still have (the key for a row without its ReSTI ID)
    assert failing == {rows[3]["Legacy Row Key"], rows[8]["ReSTI ID"], rows[9]["Legacy Row Key"]}


def test_legacy_row_key_format(v5):
    dst, rows = v5
    i, j, k = 10, 20, 30
    rows[i]["Legacy Row Key"] = "not a key"
    parts = rows[j]["Legacy Row Key"].split("|")
    parts[2] = "scene0000_00.mp4"  # a key naming another video than the row's
    rows[j]["Legacy Row Key"] = "|".join(parts)
    rows[k]["Legacy Row Key"] = rows[k]["Legacy Row Key"][:-1] + "Z"  # uid not 16 lowercase hex
    _put(dst, rows)
    v = verify_path(dst)
    assert set(v["checks"]["legacy_key_format"]["failing"]) == {rows[i]["ReSTI ID"], rows[j]["ReSTI ID"],
                                                                rows[k]["ReSTI ID"]}
    assert "scene0000_00.mp4" in v["checks"]["legacy_key_format"]["messages"][rows[j]["ReSTI ID"]]


def test_impossible_values_fail(v5):
    dst, rows = v5
    o = _first(rows, "Ego-Centric Orientation")
    d = _first(rows, "Displacement & Path Length")
    s = _first(rows, "Speed & Acceleration")
    t = _first(rows, "Trajectory Description")
    other = next(L for L in "ABCDE" if L != rows[o]["Answer"])
    rows[o]["Candidates"][other] = "1e308°"
    other = next(L for L in "ABCDE" if L != rows[d]["Answer"])
    rows[d]["Candidates"][other] = "-3.20m"
    other = next(L for L in "ABCDE" if L != rows[s]["Answer"])
    rows[s]["Candidates"][other] = "2e9m/s"
    other = next(L for L in "ABCDE" if L != rows[t]["Answer"])
    rows[t]["Candidates"][other] = "move forward 10.0m, then turn left 400°"
    _put(dst, rows)
    v = verify_path(dst)
    c = v["checks"]["value_ranges"]
    assert set(c["failing"]) == {rows[i]["ReSTI ID"] for i in (o, d, s, t)}
    assert "outside [-180°, 180°]" in c["messages"][rows[o]["ReSTI ID"]]
    assert "negative length" in c["messages"][rows[d]["ReSTI ID"]]


@pytest.mark.parametrize("what", ["resti.jsonl empty", "both row files empty"])
def test_empty_release_fails(v5, what):
    dst, _ = v5
    (dst / "resti.jsonl").write_text("", encoding="utf-8")
    if what == "both row files empty":
        (dst / "excluded.jsonl").write_text("", encoding="utf-8")
    v = verify_path(dst)
    assert not v["passed"] and v["accepted_rows"] == 0
    assert v["checks"]["non_empty"]["status"] == "fail"
    assert "counts.accepted" in v["checks"]["release_json"]["failing"]


def test_empty_release_without_release_json_still_fails(tmp_path):
    folder = write_release([], [], tmp_path / "rel")  # 0-row resti.jsonl and excluded.jsonl
    v = verify_path(folder)
    assert not v["passed"] and _failing(v) == {"non_empty": ["resti"]}
    assert v["checks"]["release_json"]["status"] == "skipped"


def test_digest_of_an_absent_file_fails(v5):
    dst, _ = v5
    with open(dst / "SHA256SUMS", "a", encoding="utf-8") as f:
        f.write("0" * 64 + "  resti.parquet\n")
    v = verify_path(dst)
    assert not v["passed"] and v["checks"]["sha256"]["failing"] == ["resti.parquet"]
    assert "absent" in json.dumps(v["checks"]["sha256"]["messages"])


def test_release_json_without_counts_fails_and_text_says_not_checked(v5, tmp_path):
    dst, _ = v5
    meta = json.loads((dst / "release.json").read_text(encoding="utf-8"))
    del meta["counts"]
    (dst / "release.json").write_text(json.dumps(meta), encoding="utf-8")
    v = verify_path(dst)
    assert not v["passed"] and v["checks"]["release_json"]["failing"] == ["counts"]
    # a release with no release.json at all: counts are not checked, and the summary says so
    (dst / "release.json").unlink()
    v = verify_path(dst)
    assert v["checks"]["release_json"]["status"] == "skipped"
    text = format_text(v)
    # (v5 itself fails the answer-interface requirements: test_verify names those rows)
    assert "NOT CHECKED release_json" in text and "(not checked: " in text.splitlines()[-1]
    assert "release_json" in text.splitlines()[-1]


def test_file_read_without_a_digest_fails(v5):
    """Dropping a file's line from SHA256SUMS does not hide its damage."""
    dst, rows = v5
    _put(dst, rows[:-1])
    meta = json.loads((dst / "release.json").read_text(encoding="utf-8"))
    meta.pop("artifacts")
    meta["counts"] = {"accepted": len(rows) - 1, "excluded": 282, "original": len(rows) + 281}
    (dst / "release.json").write_text(json.dumps(meta), encoding="utf-8")
    kept = [line for line in (dst / "SHA256SUMS").read_text().splitlines() if "resti.jsonl" not in line]
    (dst / "SHA256SUMS").write_text("\n".join(kept) + "\n")
    v = verify_path(dst)
    assert "resti.jsonl" in v["checks"]["sha256"]["failing"] and not v["passed"]


def _release(tmp_path) -> Path:
    rows = [row(rid=i, video=f"scene09{i % 3:02d}_00.mp4",
                cands={"A": f"{1 + i}.00m", "B": f"{2 + i}.50m", "C": f"{3 + i}.25m", "D": f"{4 + i}.75m",
                       "E": f"{6 + i}.10m"}) for i in range(6)]
    return seal_release(write_release(rows, [], tmp_path / "rel"))


def test_checksum_entries_stay_inside_the_release(tmp_path):
    rel = _release(tmp_path)
    secret = tmp_path / "outside.txt"
    secret.write_text("not part of the release", encoding="utf-8")
    secret_digest = hashlib.sha256(secret.read_bytes()).hexdigest()
    (rel / "escape").symlink_to(secret)
    os.mkfifo(rel / "pipe")
    (rel / "sub").mkdir()
    extra = {"../outside.txt": "path leaves the release folder", str(secret): "absolute",
             "escape": "resolves outside", "pipe": "FIFO", "sub": "folder", "/dev/zero": "absolute"}
    with open(rel / "SHA256SUMS", "a", encoding="utf-8") as f:
        f.writelines("0" * 64 + f"  {name}\n" for name in extra)
    # in a separate process with a time limit: a FIFO or a device must never be opened (it would block)
    r = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "verify", str(rel), "--json"], check=False,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr
    v = json.loads(r.stdout)
    c = v["checks"]["sha256"]
    assert set(c["failing"]) == set(extra)
    for name, why in extra.items():
        assert why in c["messages"][f"SHA256SUMS: {name}"], (name, c["messages"])
    assert secret_digest not in r.stdout  # the digest of a file outside the release is never disclosed
    assert c["detail"].startswith("2 digests checked")  # resti.jsonl and excluded.jsonl


def test_device_named_as_an_artifact_is_not_opened(tmp_path):
    rel = _release(tmp_path)
    (rel / "zero").symlink_to("/dev/zero")
    meta = json.loads((rel / "release.json").read_text())
    meta["artifacts"] = {"zero": {"bytes": 1, "sha256": "0" * 64}}
    (rel / "release.json").write_text(json.dumps(meta))
    r = subprocess.run([sys.executable, "-m", "resti_lib.run.cli", "verify", str(rel), "--json"], check=False,
                       capture_output=True, text=True, timeout=120)
    c = json.loads(r.stdout)["checks"]["sha256"]
    assert r.returncode == 1 and c["failing"] == ["zero"]
    assert "resolves outside" in c["messages"]["release.json: zero"]


def test_intact_v5_still_passes_every_check(resti_v5_dir):
    # every structural and integrity check passes; only the answer-interface requirements name rows
    v = verify_path(resti_v5_dir)
    assert set(_failing(v)) == {"separation", "plausible_given_question"}
    skipped = {k for k, c in v["checks"].items() if c["status"] == "skipped"}
    assert skipped == {"legacy_coverage", "row_files_agree"}  # no legacy file given; v5 ships resti.jsonl only


def test_row_files_that_disagree_fail_verify_and_reoption(tmp_path):
    """resti.parquet with one row removed and one Answer and Answer Detail changed, its digest re-signed:
    verify compares the two row files row for row and fails; reoption refuses the input by name."""
    import hashlib

    from resti_lib.errors import InputError
    from resti_lib.io.benchmark import rows_to_parquet_bytes
    from resti_lib.io.files import read_jsonl
    from resti_lib.release.reoption import reoption_release
    from resti_lib.release.verify import verify_path
    from tests.helpers import seal_release
    from tests.helpers import write_release as write_rows
    from tests.test_reoption import _tiny_rows

    folder = seal_release(write_rows(_tiny_rows(), [], tmp_path / "rel"))
    rows = read_jsonl(folder / "resti.jsonl")  # the rows as shipped
    bad = [dict(r) for r in rows[1:]]
    first = bad[0]
    other = next(k for k in first["Candidates"] if k != first["Answer"])
    first["Answer"], first["Answer Detail"] = other, first["Candidates"][other]
    (folder / "resti.parquet").write_bytes(rows_to_parquet_bytes(bad))
    sums = (folder / "SHA256SUMS").read_text()
    sums += f"{hashlib.sha256((folder / 'resti.parquet').read_bytes()).hexdigest()}  resti.parquet\n"
    (folder / "SHA256SUMS").write_text(sums)  # re-signed: the digests alone see nothing
    v = verify_path(folder)
    assert v["checks"]["sha256"]["status"] == "pass"
    c = v["checks"]["row_files_agree"]
    assert c["status"] == "fail" and not v["passed"]
    assert "count" in c["failing"] and any("Answer" in m for m in c["messages"].values())
    with pytest.raises(InputError) as e:
        reoption_release(folder, tmp_path / "out", seed=0)
    assert e.value.field == "row_files_agree" and not (tmp_path / "out").exists()
    # the same release with matching files passes the check
    (folder / "resti.parquet").write_bytes(rows_to_parquet_bytes(rows))
    sums = "".join(f"{hashlib.sha256((folder / n).read_bytes()).hexdigest()}  {n}\n"
                   for n in ("resti.jsonl", "resti.parquet"))
    (folder / "SHA256SUMS").write_text(sums)
    assert verify_path(folder)["checks"]["row_files_agree"]["status"] == "pass"


@pytest.mark.slow
def test_a_100_mb_release_line_is_refused_within_bounded_memory(tmp_path):
    """A release line of 100 MB is refused by name while reading at most a line limit at a time (in a
    separate process, whose peak memory is measured)."""

    from tests.helpers import seal_release
    from tests.helpers import write_release as write_rows
    from tests.test_reoption import _tiny_rows

    folder = seal_release(write_rows(_tiny_rows()[:5], [], tmp_path / "rel"))
    with (folder / "resti.jsonl").open("a") as f:
        f.write('{"Question": "' + "x" * 100_000_000 + '"}\n')
    r = subprocess.run([sys.executable, "-c", (
        "import sys\n"
        "from resti_lib.errors import InputError\n"
        "from resti_lib.io.files import read_jsonl\n"
        "try:\n    read_jsonl(sys.argv[1])\nexcept InputError as e:\n    print(e)\n"
        "print(next(int(x.split()[1]) for x in open('/proc/self/status') if x.startswith('VmHWM')))"),
        str(folder / "resti.jsonl")],
        capture_output=True, text=True, timeout=120, check=True)
    message, peak_kb = r.stdout.strip().splitlines()
    assert "line 6 is longer than" in message and "resti.jsonl" in message
    assert int(peak_kb) < 100_000  # the 100 MB line is never held whole (it was 523 MB)
