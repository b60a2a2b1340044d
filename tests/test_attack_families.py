"""Every attack family finds its own tell planted in a synthetic release, and no family false-alarms on a
clean control whose options are exchangeable (answer and distractors drawn from one distribution given the
question, letters at random). Expected accuracies of the plants are computed by hand from the plant."""

import json

import pytest

from resti_lib.options.attacks import FAMILIES, attack_table, headline
from resti_lib.options.learned import LearnedConfig
from resti_lib.run.cli import main as cli_main
from resti_lib.tasks import interface as _interface
from tests.attack_release import CELL_ROWS, PLANTS, ROWS_PER_VIDEO, release_rows
from tests.helpers import write_release

IFACE = _interface()

IFACE = _interface()

FAST_LEARNED = LearnedConfig(max_iter=40, learning_rate=0.15)

# plant -> (family, attack, task, accuracy the plant gives by construction, or None)
PLANTED = {
    "option": ("option", "max", "Displacement & Path Length", 1.0),
    "format": ("format", "fmt_decimals", "Displacement & Path Length", 1.0),
    "typicality": ("typicality", "typical_box_size", "3D Video Grounding", None),
    "question": ("question", "implied_rate_typical", "Displacement & Path Length", None),
    "premise": ("question", "premise_distance", "Pose Estimation", None),
    # rows 1-3 of each video print their answer in the next row's question; row 4 has no reveal (a 5-way tie)
    "cross_row": ("cross_row", "xrow_question", "Pose Estimation",
                  ((ROWS_PER_VIDEO - 1) + 0.2) / ROWS_PER_VIDEO),
    "metadata": ("metadata", "metadata_label", "Spatial Relation", 1.0),  # the camera decides the label
}


@pytest.fixture(scope="module")
def clean():
    return attack_table(iface=IFACE, records=release_rows(None, seed=0), families="all", learned=FAST_LEARNED)


@pytest.mark.slow  # over 3 s: make test runs it, make test-fast leaves it out
def test_clean_control_has_no_false_alarm(clean):
    assert set(clean["family"]) == set(FAMILIES) - {"keyed"}  # every blind family ran (keyed ones are named explicitly)
    assert not clean["significant"].any(), clean[clean["significant"]]
    assert 0.15 < clean["accuracy"].mean() < 0.25
    h = headline(clean)
    assert len(h) == 8 and not h["significant"].any()  # four cells and their four ALL rows


@pytest.mark.parametrize("plant", PLANTS)
def test_family_finds_its_planted_tell(plant):
    family, name, task, acc = PLANTED[plant]
    t = attack_table(iface=IFACE, records=release_rows(plant, seed=0), families="all", fast=True)
    hit = t[(t["attack"] == name) & (t["task"] == task) & (t["source"] != "ALL")].iloc[0]
    assert hit["family"] == family and hit["significant"], hit
    assert hit["n_rows"] == CELL_ROWS
    if acc is not None:
        assert hit["accuracy"] == pytest.approx(acc)
    else:
        assert hit["accuracy"] > 0.4
    # the plant changes one cell: the other cells stay at chance
    others = t[(t["task"] != task) & t["significant"]]
    assert others.empty, others


def _displacement(plant, seed):
    return [r for r in release_rows(plant, seed=seed) if r["Task"] == "Displacement & Path Length"]


@pytest.mark.parametrize("plant,name", [("option", "learned_blind"), ("question", "learned_question")])
def test_learned_families_find_planted_tells(plant, name):
    t = attack_table(iface=IFACE, records=_displacement(plant, 1), families=("learned_option", "learned_question"),
                     learned=FAST_LEARNED)
    hit = t[(t["attack"] == name) & (t["task"] == "Displacement & Path Length") & (t["source"] == "ScanNet")].iloc[0]
    assert hit["significant"] and hit["accuracy"] > 0.3, hit


def test_learned_question_reads_the_window_that_options_alone_lack():
    """The question plant: the answer implies a speed of ~0.3 m/s over its window, the distractors are drawn
    without the window. The value range alone tells little; the value over the window tells all."""
    t = attack_table(iface=IFACE, records=_displacement("question", 2), families=("learned_option", "learned_question"),
                     learned=FAST_LEARNED)
    cell = t[(t["task"] == "Displacement & Path Length") & (t["source"] == "ScanNet")].set_index("attack")
    assert cell.loc["learned_question", "accuracy"] > cell.loc["learned_blind", "accuracy"] + 0.1


def _release_dir(tmp_path, plant):
    rows = [r for r in release_rows(plant, seed=0) if r["Task"] == "Spatial Relation"]
    for r in rows:
        r.pop("ReSTI ID")
    return write_release(rows, [], tmp_path / f"rel_{plant}")


def test_cli_headline_and_fail_on_significant(tmp_path, capsys):
    leaky = _release_dir(tmp_path, "metadata")
    assert cli_main(["attack", str(leaky), "--fast"]) == 0
    out = capsys.readouterr().out
    first = out.splitlines()[0]
    assert first.startswith("**2 of 2 task/source cells have a Holm-significant blind attack**")
    assert "metadata_label" in out.split("| attack ")[1].splitlines()[2]  # the first headline row
    assert cli_main(["attack", str(leaky), "--fast", "--fail-on-significant"]) == 1
    capsys.readouterr()
    assert cli_main(["attack", str(leaky), "--families", "option", "--fail-on-significant", "--format",
                     "json"]) == 0  # the option family cannot see the camera
    cap = capsys.readouterr()
    table = json.loads(cap.out)
    assert {r["family"] for r in table} == {"option"} and cap.err == ""
    assert cli_main(["attack", str(leaky), "--fast", "--headline", "--format", "json"]) == 0
    head = json.loads(capsys.readouterr().out)
    assert [h["significant"] for h in head] == [True, True] and head[0]["attack"] == "metadata_label"
    clean = _release_dir(tmp_path, None)
    assert cli_main(["attack", str(clean), "--fail-on-significant", "--format", "csv"]) == 0
    cap = capsys.readouterr()
    assert cap.out.startswith("attack,family,task,source,n_rows,") and cap.err == ""
    assert cli_main(["attack", str(clean), "--families", "colour"]) == 2
    assert "unknown attack family" in capsys.readouterr().err


def test_cli_runs_the_keyed_family_when_named(tmp_path, capsys):
    """``--families keyed`` runs the answer-key readers (the blind suite leaves them out unless named): a
    release whose converse questions mirror each other's answers is read by keyed_converse, one row of
    each pair revealing the other (60 pairs: every row)."""
    from tests.attack_release import N_RECORDINGS, recording_rows

    rows = [r for r in recording_rows("converse", seed=0) if r["Task"] == "Spatial Relation"]
    for r in rows:
        r.pop("ReSTI ID")
    rel = write_release(rows, [], tmp_path / "converse")
    assert cli_main(["attack", str(rel), "--families", "keyed", "--format", "json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert {r["family"] for r in table} == {"keyed"}
    cell = next(r for r in table if r["attack"] == "keyed_converse" and r["source"] != "ALL")
    assert cell["significant"] and cell["hits"] == 2 * N_RECORDINGS
    # the blind suite (no family named) reads no answer key
    assert cli_main(["attack", str(rel), "--fast", "--format", "json"]) == 0
    assert "keyed" not in {r["family"] for r in json.loads(capsys.readouterr().out)}
