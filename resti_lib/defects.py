"""The vocabulary of defects and exclusion reasons.

Every detector in the audit and every injected defect in the mini-world uses these codes, so the
self-test table can compare them one to one.

Layers follow the report: ``question`` (the contract is incomplete), ``source`` (the legacy value
disagrees with the source under a stated operator), ``answer`` (the five options and the key).
``category`` groups codes into the report's six defect-report categories (audit overview, panel b).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Defect:
    code: str
    layer: str  # question | source | answer
    category: str
    description: str


_DEFECTS = [
    # question layer
    Defect("pose_time_omitted", "question", "omitted time",
           "pose question does not state the time at which the pose is asked"),
    Defect("unnamed_frame", "question", "unnamed frame",
           "grounding question refers to an unnamed sampled video time"),
    Defect("ambiguous_subject", "question", "ambiguous subject",
           "motion question names two possible subjects (camera or object)"),
    Defect("zero_length_interval", "question", "structural",
           "the asked interval has zero length"),
    Defect("premise_equals_answer", "question", "structural",
           "the answer is printed in the premise (target time equals premise time)"),
    Defect("premise_reveals_answer", "question", "structural",
           "the premise pose printed in the question is the answer of another question of the same recording "
           "(a converse pair: the pose at t1 given t0, and at t0 given t1)"),
    Defect("grouped_referent", "question", "referent",
           "the description names a group of objects, not one instance"),
    Defect("multiple_instances", "question", "referent",
           "several source instances match the description"),
    Defect("no_source_instance", "question", "referent",
           "no source instance matches the description"),
    Defect("not_visible", "question", "referent",
           "the referent is not visible at the asked frame"),
    Defect("unit_tag_missing", "question", "unit tag",
           "the question does not state the unit of the answer"),
    Defect("statistic_unnamed", "question", "unnamed statistic",
           "the question leaves the statistic open ('average speed', 'how far has X traveled') and the "
           "value is the endpoint-displacement reading"),
    Defect("duplicate_row", "question", "structural",
           "the legacy row is an exact copy of another row of the benchmark (every field equal)"),
    Defect("time_past_video_end", "question", "structural",
           "an asked time lies after the end of the video (the last source sample plus one interval)"),
    # source layer
    Defect("grounding_alignment_omitted", "source", "source geometry",
           "camera-frame box computed as P(t)^-1 c_ann (axis alignment omitted)"),
    Defect("orientation_xz_plane", "source", "source geometry",
           "orientation measured on the raw-world X-Z (vertical) plane, not heading"),
    Defect("waymo_pose_wrong_timestamp", "source", "source geometry",
           "pose matrix taken from a different timestamp than the one asked"),
    Defect("speed_is_displacement_over_time", "source", "source geometry",
           "'average speed' value equals endpoint displacement / elapsed time"),
    Defect("distance_traveled_is_displacement", "source", "source geometry",
           "'how far has X traveled' value equals the endpoint displacement, not the path length"),
    Defect("trajectory_10m_grid", "source", "source geometry",
           "trajectory distances rounded to a 10 m grid"),
    Defect("value_mismatch", "source", "source geometry",
           "legacy value disagrees with the source beyond rounding"),
    # answer layer
    Defect("key_detail_mismatch", "answer", "key-detail mismatch",
           "the keyed candidate disagrees with the Answer Detail"),
    Defect("duplicate_options_exact", "answer", "duplicate options",
           "two candidates are the same string"),
    Defect("duplicate_options_numeric", "answer", "duplicate options",
           "two candidates differ in text but encode the same value"),
    Defect("orientation_symmetric_grid", "answer", "option shortcut",
           "distractors at +-7.5 and +-15 degrees around the answer"),
    Defect("orientation_smallest_correct", "answer", "option shortcut",
           "the correct value is the smallest candidate"),
    Defect("pose_identical_rotations", "answer", "option shortcut",
           "pose distractors reuse the answer's rotation"),
]

DEFECTS: dict[str, Defect] = {d.code: d for d in _DEFECTS}

# The report's six construction-defect categories of the released questions and options (audit
# overview, panel b); source-level geometric and temporal failures are counted separately.
REPORT_CATEGORIES = ("key-detail mismatch", "duplicate options", "omitted time", "unnamed frame",
                     "ambiguous subject", "unit tag")

# Exclusion reasons (a row ends excluded with one or more of these, plus evidence).
REASONS: dict[str, str] = {
    "ambiguous_instance": "several source instances match the description",
    "grouped_referent": "the description names a group, not one instance",
    "no_source_instance": "no source instance matches the description",
    "not_visible_at_frame": "the referent is outside the camera frustum at the asked frame",
    "zero_length_interval": "the interval has zero length",
    "premise_equals_target": "the target pose is the premise pose",
    "no_unrevealing_premise": "the premise is another question's answer and no time of the recording can replace it "
                              "(every valid time is a target of a question of the recording)",
    "ambiguous_subject": "two possible motion subjects and the source does not decide",
    "no_dominant_relation": "no spatial relation dominates by the margin",
    "undefined_dimension": "the asked dimension has no convention for this object",
    "invalid_pose_at_time": "the source pose is invalid at the asked time",
    "malformed_row": "the legacy row cannot be parsed",
    "duplicate_row": "an exact copy of an earlier legacy row, which is kept and audited once",
    "time_past_video_end": "an asked time lies after the end of the video",
    "unsupported_question": "the question does not match a known contract for the task",
    "source_damaged": "a source file the row needs fails a check of what it must hold (file, row and field in "
                      "the evidence)",
    "source_gap": "the source's samples inside the question's window are further apart than the stated "
                  "multiple of their sampling interval (max_gap_factor, params/measure.yaml): not interpolated",
    "no_valid_options": "no five candidates meet the answer interface's requirements (separation, physical "
                        "possibility) for this answer under the run's option params",
}
