"""Per-kind builders of the option stage, one module per answer kind, in one registry.

A :class:`KindBuilder` fits a group model from the answers of a group (:meth:`KindBuilder.fit`) and
draws one candidate set for a row (:meth:`KindBuilder.build`); the stage (:mod:`resti_lib.options.stage`)
owns planning, calibration, letters and the build loop and dispatches by the row's answer kind
(:data:`BUILDERS`). A new kind plugs in with :func:`register_kind`.
"""

from __future__ import annotations

import importlib

BUILDERS: dict[str, "KindBuilder"] = {}
_MODULES = ("scalar", "angle", "trajectory", "box", "pose", "label")


class KindBuilder:
    """Fit and draw for one answer kind (see the module docstring)."""

    kind = ""

    def fit(self, st, g: str, ps: list):
        """The group model of group ``g`` (rows ``ps``) under the stage ``st``."""
        from ..plan import GroupModel

        return GroupModel(self.kind)

    def build(self, st, p, gm, s: float, rng, strict: bool, reveals: dict) -> list[str]:
        """Five candidate strings (the answer among them) for row ``p``; raises ``Reject`` to redraw."""
        raise NotImplementedError

    def near(self, st, a, b) -> bool:
        """Do the answers of rows ``a`` and ``b`` agree within the separation floor (so that their
        candidate sets can be coupled)? Kinds that cannot couple say no."""
        return False

    def translate(self, st, base, p, strings: list[str]) -> list[str] | None:
        """Row ``p``'s candidates as the translate of ``base``'s ``strings`` by the difference of
        their answers (``p``'s own answer in the answer's place), or None when they cannot be."""
        return None


def register_kind(kind: str):
    """Class decorator: register a builder for ``kind``."""
    def deco(cls):
        cls.kind = kind
        BUILDERS[kind] = cls()
        return cls
    return deco


def builder_for(kind: str) -> KindBuilder:
    """The builder of ``kind``. Every kind module is loaded on the first request for a kind not yet
    registered (a module imported on its own, for one of its helpers, registers only its own kind)."""
    if kind not in BUILDERS:
        for m in _MODULES:
            importlib.import_module(f"{__name__}.{m}")
    if kind not in BUILDERS:
        raise KeyError(f"no option builder for answer kind {kind!r} (kinds: {', '.join(sorted(BUILDERS))})")
    return BUILDERS[kind]


__all__ = ["BUILDERS", "KindBuilder", "builder_for", "register_kind"]
