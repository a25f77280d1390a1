"""Formatting shared by the benchmarks that compare a "before" and an "after" value per scene."""

from __future__ import annotations

import numpy as np


def dash(value, fmt: str) -> str:
    """``value`` formatted, or an en dash when there is none."""
    return "–" if value is None else format(value, fmt)


def before_after(before, after, fmt: str) -> str:
    """``mean → mean mean, median → median median, better on k of n`` for paired per-scene values (lower is
    better)."""
    x, y = np.asarray(before, float), np.asarray(after, float)
    return (f"{np.mean(x):{fmt}} → {np.mean(y):{fmt}} mean, {np.median(x):{fmt}} → {np.median(y):{fmt}} "
            f"median, better on {int(np.sum(y < x))} of {len(x)}")
