"""Labels: the fixed labels of the source, in a seeded order."""

from __future__ import annotations

from ...errors import OptionError
from ..plan import RowPlan
from . import KindBuilder, register_kind


@register_kind("label")
class LabelKind(KindBuilder):
    """Labels: the fixed labels of the source, in a seeded order."""

    def build_label(self, st, p: RowPlan, record: dict) -> list[str]:
        labels = list(p.spec.labels) or list(p.spec.extra.get("labels") or [])
        if p.spec.detail not in labels or len(set(labels)) != 5:
            raise OptionError(f"{p.rid}: the row's candidates are not five distinct labels containing "
                              f"{p.spec.detail!r}")
        return sorted(labels)
