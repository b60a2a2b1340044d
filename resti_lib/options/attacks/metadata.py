"""Family ``metadata``: non-video fields, here the Waymo camera in the video name.

``metadata_label`` (labels and trajectory structures) learns the most frequent answer per camera on one
half of the source sequences and tests it on the other (both ways; a majority vote that leaves one row
out is not an exact test, its rows share their luck); ``metadata_value`` (numbers) scores candidates by
their density among the answers of other sequences with the same camera.
"""

from __future__ import annotations

from .batch import Batch
from .common import directional
from .features import question_kind, value_scale
from .reference import loo_density, majority_label, split_halves
from .registry import attack


def _camera_key(batch: Batch, i: int):
    o = batch.obs[i]
    return None if o.camera is None else (batch.rows[i].task, batch.rows[i].source, question_kind(o), o.camera)


@attack("metadata_label", ["label", "trajectory"], "most frequent answer label (trajectory: structure) per camera in "
        "the video name, learned on one half of the source sequences and tested on the other (both ways)",
        family="metadata", scope="batch")
def _metadata_label(batch: Batch):
    return split_halves(batch, lambda train, test: majority_label(batch, train, test,
                                                                   lambda i: _camera_key(batch, i)))


@attack("metadata_value", ["scalar", "trajectory"], "candidate most or least typical of the answers of the other "
        "rows of other source sequences with the same camera in the video name and question type (in every "
        "direction)",
        family="metadata", scope="batch")
def _metadata_value(batch: Batch):
    vals = [value_scale(p) for p in batch.rows]
    dens = loo_density(batch, vals, lambda i: _camera_key(batch, i))
    return directional(batch, dens)
