"""The attack registry: the families, the :class:`Attack` type, the :func:`attack` decorator and
:func:`select`.

Every family module of this package registers its attacks on import; the package imports them all,
so the registry is complete whenever any module of :mod:`resti_lib.options.attacks` is in use.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

FAMILIES = {
    "option": "option-only rules on the candidate values",
    "format": "formatting tells of the printed candidates (and their tie sets)",
    "typicality": "field typicality against the other rows' answers",
    "prior": "priors over the other recordings of the release: string and field rates, nearest candidate sets, the "
             "echo of the answers in the other recordings' distractors",
    "question": "question-aware rules (window, premise pose, direction of travel, question type and noun)",
    "cross_row": "same-video / same-sequence cross-row reveals",
    "relation": "physical relations across the rows of one recording (rates, paths, box edges, poses, turns, "
                "converse relations)",
    "metadata": "metadata (video name and other non-video fields)",
    "learned_option": "learned attacker on candidate features",
    "learned_question": "learned attacker on candidate, population and question features",
    "keyed": "readers of other rows' answer keys (a harness that shows a sibling question's key): what a repeated "
             "question or physics reveals from a sibling's answer; no option design can hide that, so it is not "
             "part of the blind suite: the evaluation subset leaves such rows out",
}
LEARNED_FAMILIES = ("learned_option", "learned_question")
#: Families that read a sibling row's answer key, not only what a blind reader sees.
KEYED_FAMILIES = ("keyed",)
KINDS = ("scalar", "angle", "box", "pose", "trajectory", "label", "any")
SCOPES = ("row", "question", "batch")


@dataclass
class Attack:
    """A registered attack. ``scope``: ``row`` (``fn(p)``), ``question`` (``fn(p, obs)``) or ``batch``
    (``fn(batch)`` -> one pick per usable row). ``tests``: comparisons made inside the attack
    (Bonferroni factor of its p-value)."""

    name: str
    kinds: tuple
    fn: Callable
    description: str
    family: str = "option"
    scope: str = "row"
    tests: int = 1

    @property
    def learned(self) -> bool:
        return self.family in LEARNED_FAMILIES


ATTACKS: dict[str, Attack] = {}


def attack(name: str, kinds: Iterable[str], description: str, *, family: str = "option", scope: str = "row",
           tests: int = 1):
    """Register an attack (decorator). ``kinds``: value kinds it reads (``scalar``, ``angle``, ``box``,
    ``pose``, ``trajectory``, ``label``, ``any``); row and question attacks run only on rows of those
    kinds. A second attack of the same name is refused."""
    if family not in FAMILIES:
        raise ValueError(f"unknown attack family {family!r}; known: {sorted(FAMILIES)}")
    if scope not in SCOPES:
        raise ValueError(f"unknown attack scope {scope!r}")
    kinds = tuple(kinds)
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        raise ValueError(f"unknown value kind(s) {bad} of attack {name!r}; known: {list(KINDS)}")

    def deco(fn):
        if name in ATTACKS and ATTACKS[name].fn is not fn:
            raise ValueError(f"attack {name!r} is registered twice")
        ATTACKS[name] = Attack(name, kinds, fn, description, family, scope, tests)
        return fn
    return deco


def family_of(name: str) -> str:
    """The family of a registered attack (``option`` for a name the registry does not know)."""
    return ATTACKS[name].family if name in ATTACKS else "option"


def select(families=None, attacks=None, *, fast: bool = False) -> list[str]:
    """Attack names of the chosen ``families`` (None or ``"all"``: every blind family, the keyed ones
    named explicitly) and/or ``attacks``
    (names; None: every attack of the families); ``fast`` leaves the learned families out. Unknown
    names raise ``ValueError``."""
    if families in (None, "all"):  # the blind suite: every family that reads no answer key
        fams = [f for f in FAMILIES if f not in KEYED_FAMILIES]
    else:
        fams = [families] if isinstance(families, str) else list(families)
        bad = [f for f in fams if f not in FAMILIES]
        if bad:
            raise ValueError(f"unknown attack family(ies) {bad}; known: {list(FAMILIES)}")
    if attacks in (None, "all"):
        names = [n for n, a in ATTACKS.items() if a.family in fams]
    else:
        names = [attacks] if isinstance(attacks, str) else list(attacks)
        bad = [n for n in names if n not in ATTACKS]
        if bad:
            raise ValueError(f"unknown attack(s) {bad}; known: {sorted(ATTACKS)}")
        names = [n for n in names if ATTACKS[n].family in fams]
    if fast:
        names = [n for n in names if not ATTACKS[n].learned]
    return names
