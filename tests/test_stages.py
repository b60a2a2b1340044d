"""Stage bookkeeping without running notebooks: waves and needs of the default stage list, what
``--only`` adds downstream, fingerprints of inputs, and when a recorded stage is stale."""

import os

import pytest
import yaml

from resti_lib import paths
from resti_lib.errors import InputError
from resti_lib.run.plan import downstream, main_config, match_only, plan
from resti_lib.run.stages import Fingerprints, State, fingerprint, scan, stage_key

TASK_STAGES = ["01_grounding", "02_orientation", "03_dimensional", "04_relation", "05_displacement", "06_speed",
               "07_trajectory", "08_pose"]


@pytest.fixture
def default_stages():
    cfg = main_config()
    return cfg["stages"], {k: v for k, v in cfg.items() if k != "stages"}


def test_default_plan_with_and_without_the_reference(default_stages, tmp_path):
    stages, common = default_stages
    ref = tmp_path / "reference"
    ref.mkdir()
    by = {s["notebook"]: s for s in stages}
    own = yaml.safe_load((paths.ROOT / by["00_answer_interface"]["params"]).read_text())
    assert own["release_path"]  # the audit of 00 reads release_path from its own params
    # with the reference present: 00 runs beside 99 and needs no task; 99 needs every task
    with_ref = {**by["00_answer_interface"], "params": None, "wave_if_missing": {"param": "release_path", "wave": 5}}
    st = [by[n] for n in TASK_STAGES] + [by["99_release_report"], with_ref]
    waves, needs = plan(st, {**common, "release_path": str(ref)})
    assert waves["00_answer_interface"] == 4 and needs["00_answer_interface"] == []
    assert needs["99_release_report"] == TASK_STAGES
    # without it: 00 audits our release, after 99, and needs everything before it
    waves, needs = plan(st, {**common, "release_path": str(tmp_path / "absent")})
    assert waves["00_answer_interface"] == 5
    assert needs["00_answer_interface"] == [*TASK_STAGES, "99_release_report"]


def test_only_adds_what_is_downstream(default_stages, tmp_path, monkeypatch):
    stages, common = default_stages
    (tmp_path / "data" / "resti_v5").mkdir(parents=True)
    monkeypatch.setenv("RESTI_SHARED", str(tmp_path))  # the reference release is present
    _, needs = plan(stages, common)
    assert match_only(stages, ["dimensional"]) == ["03_dimensional"]
    assert downstream(["04_relation"], needs, stages) == ["99_release_report"]
    # a task whose candidate sets another task's follow: that task too
    assert downstream(["03_dimensional"], needs, stages) == ["01_grounding", "99_release_report"]
    assert downstream(["99_release_report"], needs, stages) == []
    with pytest.raises(InputError, match="at least one stage"):
        match_only(stages, [])
    with pytest.raises(InputError, match=r"unknown stage\(s\) \['nope'\]"):
        match_only(stages, ["nope"])


def test_fingerprints_follow_content_and_skip_outputs(tmp_path):
    out = tmp_path / "outputs"
    out.mkdir()
    f = tmp_path / "qa.parquet"
    f.write_bytes(b"abc")
    a = fingerprint(f)
    os.utime(f, ns=(1, 1))
    assert fingerprint(f) == a  # a file by its content, not its time
    f.write_bytes(b"abd")
    assert fingerprint(f) != a
    d = tmp_path / "scans"
    (d / "s1").mkdir(parents=True)
    (d / "s1" / "x.txt").write_text("1")
    t = fingerprint(d)
    (d / "s1" / "y.txt").write_text("2")
    assert fingerprint(d) != t  # a folder by its files' names, sizes and times
    inputs = Fingerprints(out).inputs({"legacy_benchmark": str(f), "scannet_root": str(d), "output_dir": str(out),
                                       "world_dir": str(tmp_path), "pose_rule": "linear", "decimals": 2})
    # tmp_path holds the outputs: not an input; names that are not paths are ignored
    assert sorted(inputs) == ["legacy_benchmark", "scannet_root"]


def test_state_staleness(tmp_path):
    out = tmp_path / "outputs"
    (out / "tables").mkdir(parents=True)
    nb = tmp_path / "x.ipynb"
    nb.write_text("{}")
    key = stage_key(nb, {"a": 1, "output_dir": "o1"}, code="c", env={}, inputs={}, needs={})
    assert stage_key(nb, {"a": 1, "output_dir": "o2"}, code="c", env={}, inputs={}, needs={}).key == key.key
    st = State(out)
    assert st.stale_reason("x", key, {}) == "never run here"
    before = scan(out, [])
    (out / "tables" / "t.csv").write_text("a\n1\n")
    after = scan(out, [])
    st.record(["x"], {"x": key.parts()}, {"x": 1.0}, before, after)
    st.save()
    st = State(out)  # read back from disk
    assert st.stale_reason("x", key, scan(out, [])) is None
    other = stage_key(nb, {"a": 2}, code="c", env={}, inputs={}, needs={})
    assert st.stale_reason("x", other, scan(out, [])) == "params changed"
    upstream = stage_key(nb, {"a": 1}, code="c", env={}, inputs={}, needs={"y": "k2"})
    assert st.stale_reason("x", upstream, scan(out, [])) == "upstream stages changed"
    (out / "tables" / "t.csv").unlink()  # a product removed by hand
    assert "output file(s) changed or missing, e.g. tables/t.csv" in st.stale_reason("x", key, scan(out, []))


def test_run_skips_up_to_date_stages_and_only_refreshes_downstream(tmp_path, monkeypatch, capsys):
    """The stage logic of ``resti run`` with notebooks replaced by a stand-in that writes each
    stage's files (no kernel): what runs, what is skipped, what ``--only`` leaves and says."""
    import resti_lib.run.pipeline as P
    from resti_lib.run.notebooks import NotebookRun

    (tmp_path / "shared" / "data" / "resti_v5").mkdir(parents=True)
    monkeypatch.setenv("RESTI_SHARED", str(tmp_path / "shared"))  # the reference exists: 00 beside 99
    out = tmp_path / "out"
    calls = []

    def fake_run_notebook(nb, params, *, out_dir, html_dir):
        calls.append(nb.stem)
        assert ("run_context" in params) == (nb.stem == "99_release_report")
        for p in (out_dir / nb.name, html_dir / f"{nb.stem}.html", out / "tables" / f"{nb.stem}.csv"):
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(f"{nb.stem} {sorted(params)}\n")
        return NotebookRun(nb.stem, out_dir / nb.name, html_dir / f"{nb.stem}.html", 0.01)

    monkeypatch.setattr(P, "run_notebook", fake_run_notebook)
    cfg = main_config()
    for k in ("world_dir", "legacy_benchmark"):
        cfg.pop(k)
    grounding = tmp_path / "grounding.yaml"
    grounding.write_text((paths.PARAMS / "grounding.yaml").read_text())
    for s in cfg["stages"]:
        if s["notebook"] == "01_grounding":
            s["params"] = str(grounding)
    cfg["output_dir"] = str(out)
    main = tmp_path / "main.yaml"
    main.write_text(yaml.safe_dump(cfg))
    every = [s["notebook"] for s in cfg["stages"] if not s.get("on_demand")]

    def run(**kw):
        calls.clear()
        assert P.run(main, **kw) == 0
        return set(calls)

    assert run() == set(every)
    assert (out / "report" / "index.html").exists()
    assert run() == set()  # nothing changed
    grounding.write_text(grounding.read_text().replace("alpha: 0.05", "alpha: 0.01"))
    capsys.readouterr()
    assert run(only=["relation"]) == {"04_relation"}  # its key did not change: 99 stays
    err = capsys.readouterr().err
    assert "stale stages not run: 01_grounding (params changed)" in err
    assert "99_release_report" not in err  # 99 is consistent with the outputs it read
    assert run() == {"01_grounding", "99_release_report"}  # the edit, then what is downstream
    (out / "tables" / "05_displacement.csv").unlink()  # an output removed by hand
    assert run() == {"05_displacement"}  # rewritten identically: nothing downstream changes
    assert run(force=True) == set(every)
    assert run(only=["90_reoption_release"]) == {"90_reoption_release"}  # on demand, needs nothing


def test_a_wave_starts_its_longest_stages_first(tmp_path):
    """Two workers, stages of 1, 4, 5 and 9 s last time: in params order the 9 s stage starts last,
    at 4 s, and the wave lasts 13 s; longest first it lasts 10 s (9 | 5 + 4, then 1). Stages never
    run go first, in params order."""
    from resti_lib.run.pipeline import longest_first
    from resti_lib.run.stages import State

    st = State(tmp_path)
    for n, s in {"a": 1.0, "b": 4.0, "c": 5.0, "d": 9.0}.items():
        st.stages[n] = {"seconds": s}
    order = longest_first(["a", "b", "new2", "c", "d", "new1"], st)
    assert order == ["new2", "new1", "d", "c", "b", "a"]

    def makespan(names, workers=2):  # list scheduling, by hand
        free = [0.0] * workers
        for n in names:
            k = free.index(min(free))
            free[k] += st.stages[n]["seconds"]
        return max(free)

    assert makespan(["a", "b", "c", "d"]) == 13.0
    assert makespan(longest_first(["a", "b", "c", "d"], st)) == 10.0
