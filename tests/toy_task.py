"""A toy ninth task, defined outside the package: how far the camera is from the scan origin at a
time. It supplies only its descriptor, contract reader, a measure operator and its rewrite (the
default scalar diagnosis); the shared runner does the rest. :func:`toy_registered` registers it for
the tests that use it and removes it after, so other tests see the eight built-in tasks.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from resti_lib import values as V
from resti_lib.adjudicate import Rule
from resti_lib.contract import Contract, base_contract, instant
from resti_lib.errors import ContractError
from resti_lib.geometry import trajectory as G
from resti_lib.measure import MeasureContext, register_operator
from resti_lib.tasks import register_task, unregister_task
from resti_lib.tasks.base import AnswerSpec, Case, Exclude, Task

TOY = "Toy Camera Range"


@register_operator("toy_camera_range", unit="m", n_times=(1,), entities=("camera",))
def _op_toy_range(ctx: MeasureContext):
    """Distance of the camera centre from the world origin at ``times[0]`` (m)."""
    et = ctx.entity_track()
    T, ev = G.pose_at(et.track, ctx.t0, ctx.rule, ctx.tol)
    ev["files"] = et.track.source
    return float(np.linalg.norm(T[:3, 3])), ev


class ToyRange(Task):
    name = TOY
    params_name = "toy_range"
    notebook = "09_toy_range"
    answer_kind = "scalar"
    rule_key = None
    quantity = "distance_to_camera"
    figures = {"ranges": "Toy task: the camera's distance from the scan origin per asked time."}
    legacy_kind = V.Scalar
    operators = ("toy_camera_range",)

    def read_contract(self, r: dict, video_map: dict | None = None) -> Contract:
        c, _ = base_contract(r, "toy_camera_range", video_map=video_map)
        c.entity, c.times = {"kind": "camera"}, instant(c, r)
        if not c.unit_stated:
            c.miss("unit")
        return c

    def reconstruct(self, case: Case) -> None:
        try:
            m = case.measure("toy_camera_range", {"kind": "camera"}, case.contract.times)
        except ContractError as e:
            raise Exclude("invalid_pose_at_time", t=case.contract.times, error=str(e)) from None
        case.value = m.value
        case.rule = Rule().to_dict()
        case.outcome.time_start = case.outcome.time_end = case.contract.times[0]
        case.provenance(files=[m.evidence["files"]], frames={"indices": m.evidence["indices"]}, chain="|p(t)|")
        case.observables["subject"] = "the camera"
        case.answer = AnswerSpec("scalar", m.value, "m", 2)

    def rewrite(self, case: Case) -> str:
        return (f"At t={V.format_seconds(case.contract.times[0])} s, how far is the camera centre from the origin "
                f"of the ScanNet raw scan frame? (unit: m)")

    def settings(self, params: dict | None) -> dict:
        """The toy has no params file: its settings are the run's params."""
        return dict(params or {})


@contextmanager
def toy_registered():
    """The toy task registered for the duration of the block."""
    register_task(ToyRange)
    try:
        yield ToyRange
    finally:
        unregister_task(TOY)
