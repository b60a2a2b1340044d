"""The blind attack suite: pick a letter without the video (registry, scoring, one module per family).

Importing the package registers every family. Layout: ``registry`` (the families, ``Attack``,
``attack``, ``select``), ``batch`` (the rows as attacks see them), ``common`` (picks, ties, directions),
``features`` and ``reference`` (what a row says, and the other recordings' answers), ``scoring``
(p-values, Holm, power, large effects, the table, its headline), and the families ``option``,
``format``, ``typicality``, ``prior``, ``question``, ``cross_row``, ``relation``, ``metadata`` and
``learned``. New attacks plug in with :func:`attack` (see ``README.md``, "An attack").
"""

from . import cross_row, format, learned, metadata, option, prior, question, relation, typicality  # noqa: F401
from .batch import Batch, kind_of, make_batch, parse_rows  # noqa: F401
from .common import ALL5, CHANCE, DIRECTIONS, TIE, Directional, as_pick, directional, expected_hit, extreme, top  # noqa: F401
from .registry import ATTACKS, FAMILIES, LEARNED_FAMILIES, Attack, attack, select  # noqa: F401
from .scoring import (  # noqa: F401
    COLUMNS,
    HEADLINE_COLUMNS,
    LARGE_EFFECT_AT,
    LARGE_EFFECT_MIN_ROWS,
    OPTION_ONLY,
    PICK_COLUMNS,
    attack_table,
    binom_p,
    headline,
    holm,
    holm_adjusted,
    large_effects,
    picks_frame,
    run_one,
    run_picks,
    strongest,
    summarize_picks,
    tie_aware_p,
    tie_aware_p_counts,
)
