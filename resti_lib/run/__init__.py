"""The run wing: the main job (:mod:`.pipeline`, stages skipped when unchanged: :mod:`.stages`, the
run block of the report: :mod:`.runinfo`), papermill execution (:mod:`.notebooks`) and the ``resti``
console script (:mod:`.cli`)."""
