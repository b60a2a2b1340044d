"""The power of the blind attack tests: the smallest blind accuracy a test detects.

An attack table states, per task/source cell, the smallest true blind accuracy that the exact
one-sided test detects with 80% power at the cell's size and at Holm's first-step level
``alpha / rows`` (the level at which any single leak of the table is found whatever the other rows
show), so that "no significant attack" is read with its power. A cell that cannot detect a 35% blind
accuracy is *underpowered*.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

POWER = 0.8            # power at which the detectable accuracy is stated
UNDERPOWERED_AT = 0.35  # a cell that cannot detect this blind accuracy is marked underpowered


def critical_hits(n: int, level: float, chance: float = 0.2) -> int:
    """Smallest hit count ``k`` with ``P[X >= k] <= level`` for ``X ~ Binomial(n, chance)``
    (``n + 1`` when even ``n`` hits are not significant)."""
    from scipy.stats import binom

    if n <= 0:
        return 1
    k = np.arange(n + 1)
    sf = binom.sf(k - 1, n, chance)  # P[X >= k]
    ok = np.flatnonzero(sf <= level)
    return int(ok[0]) if len(ok) else n + 1


def min_detectable_accuracy(n: int, level: float, *, power: float = POWER, chance: float = 0.2) -> float:
    """The smallest true blind accuracy that an exact one-sided binomial test at ``level`` detects with
    probability ``power`` on ``n`` rows; ``nan`` when no accuracy can be detected (``n`` too small).

    The test rejects when the hits reach :func:`critical_hits`; the power at accuracy ``q`` is
    ``P[Binomial(n, q) >= k]``, increasing in ``q``, solved for ``power`` by bisection.
    """
    from scipy.optimize import brentq
    from scipy.stats import binom

    k = critical_hits(n, level, chance)
    if n <= 0 or k > n:
        return float("nan")
    f = lambda q: float(binom.sf(k - 1, n, q)) - power
    if f(chance) >= 0:
        return float(chance)
    return float(brentq(f, chance, 1.0, xtol=1e-6))


def attack_power(n_rows, tests: int, *, alpha: float = 0.05, power: float = POWER, chance: float = 0.2,
                 underpowered_at: float = UNDERPOWERED_AT) -> pd.DataFrame:
    """Per cell size: the smallest blind accuracy detectable with ``power`` when the test is run at
    Holm's first step ``alpha / tests`` (the level at which any single leak of the table is found
    whatever the other rows show), and whether that exceeds ``underpowered_at``.

    Returns a frame with columns ``n_rows, level, min_detectable, underpowered`` (one row per distinct
    ``n_rows``, in input order).
    """
    level = alpha / max(int(tests), 1)
    sizes = list(dict.fromkeys(int(n) for n in n_rows))
    md = [min_detectable_accuracy(n, level, power=power, chance=chance) for n in sizes]
    return pd.DataFrame({"n_rows": sizes, "level": level, "min_detectable": md,
                         "underpowered": [not (m <= underpowered_at) for m in md]})


def clopper_pearson(hits, n, level: float = 0.95):
    """Exact binomial confidence interval for hits/n (arrays allowed)."""
    from scipy.stats import beta  # imported here: most figures do not need scipy

    hits, n = np.asarray(hits, float), np.asarray(n, float)
    a = (1 - level) / 2
    lo = np.where(hits > 0, beta.ppf(a, np.maximum(hits, 1e-12), n - hits + 1), 0.0)
    hi = np.where(hits < n, beta.ppf(1 - a, hits + 1, np.maximum(n - hits, 1e-12)), 1.0)
    return lo, hi
