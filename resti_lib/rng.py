"""Deterministic randomness: one RNG per row from its stable key, balanced schedules per group."""

from __future__ import annotations

import hashlib
from typing import Iterable, Sequence

import numpy as np


def stable_seed(*parts: object) -> int:
    """A 64-bit seed from the sha256 of the parts' text (never Python's salted ``hash``)."""
    text = "\x1f".join(str(p) for p in parts)
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "little")


def row_rng(seed: int, key: str, purpose: str = "") -> np.random.Generator:
    """The RNG of one row (``key`` = its stable key, ``purpose`` separates independent streams)."""
    return np.random.default_rng(stable_seed(seed, purpose, key))


def balanced_schedule(keys: Iterable[str], levels: Sequence, *, seed: int, group: str) -> dict:
    """Assign each key one of ``levels`` so that counts differ by at most one within the group.

    The keys are sorted (so the result does not depend on input order), the levels are laid out
    cyclically, and the layout is shuffled with a seed derived from ``group``.
    """
    ks = sorted(set(keys))
    n, m = len(ks), len(levels)
    if n == 0:
        return {}
    rng = np.random.default_rng(stable_seed(seed, "schedule", group))
    # shuffle the order in which levels are used, then which key gets which slot
    start = int(rng.integers(m))
    layout = [levels[(i + start) % m] for i in range(n)]
    perm = rng.permutation(n)
    return {ks[i]: layout[perm[i]] for i in range(n)}
