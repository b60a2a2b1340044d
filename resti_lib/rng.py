"""Deterministic randomness: one RNG per row from its stable key."""

from __future__ import annotations

import hashlib

import numpy as np


def stable_seed(*parts: object) -> int:
    """A 64-bit seed from the sha256 of the parts' text (never Python's salted ``hash``)."""
    text = "\x1f".join(str(p) for p in parts)
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "little")


def row_rng(seed: int, key: str, purpose: str = "") -> np.random.Generator:
    """The RNG of one row (``key`` = its stable key, ``purpose`` separates independent streams)."""
    return np.random.default_rng(stable_seed(seed, purpose, key))


