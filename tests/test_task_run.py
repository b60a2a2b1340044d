"""The per-task run summary: counts that do not depend on the interpreter's string hashing."""

from resti_lib.tasks.base import Outcome
from resti_lib.tasks.run import TaskRun


def _outcome(row, defects):
    return Outcome(row=row, key=f"k{row}", task="T", source="ScanNet", video="v", legacy_id=row,
                   verdict="retained", defects=defects)


def test_defect_counts_rows_once_and_ties_keep_first_appearance():
    codes = ["value_mismatch", "unit_tag_missing", "ambiguous_subject", "unnamed_frame", "pose_time_omitted",
             "trajectory_10m_grid", "orientation_xz_plane", "key_detail_mismatch"]
    # row 0 lists every code once and "value_mismatch" twice; row 1 lists "unnamed_frame" again
    outcomes = [_outcome(0, [*codes, "value_mismatch"]), _outcome(1, ["unnamed_frame"])]
    counts = TaskRun("T", outcomes, None, None, None).defects
    # by hand: unnamed_frame in 2 rows, every other code in 1 row (a row counts a code once),
    # ties in the order the codes first appear
    assert list(counts.index) == ["unnamed_frame"] + [c for c in codes if c != "unnamed_frame"]
    assert list(counts) == [2] + [1] * 7
