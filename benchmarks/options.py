"""Command-line overrides shared by the benchmarks: ``FIELD=VALUE`` strings as keyword arguments."""

from __future__ import annotations

import inspect
from types import SimpleNamespace


def field_overrides(defaults, pairs: list[str], name: str | None = None) -> dict:
    """``FIELD=VALUE`` strings (``--bg``, ``--tracker``) as keyword arguments for ``defaults``' class, each value
    converted to its field's type: booleans from 1/true/yes, tuples from comma-separated numbers (also for a field
    whose default is None, e.g. ``loose=-1,0,-1,0``)."""
    out = {}
    for pair in pairs:
        k, _, v = pair.partition("=")
        if not hasattr(defaults, k):
            raise SystemExit(f"{name or type(defaults).__name__} has no field {k!r} ({pair!r})")
        default = getattr(defaults, k)
        if isinstance(default, bool):
            out[k] = v.lower() in ("1", "true", "yes")
        elif isinstance(default, tuple):
            out[k] = tuple(float(x) for x in v.split(","))
        elif isinstance(default, (int, float)):
            out[k] = type(default)(float(v))
        elif default is None:
            out[k] = _untyped(v)
        else:
            out[k] = v
    return out


def _untyped(v: str):
    """A value for a field whose default is None: comma-separated numbers as a tuple, one number as a float,
    anything else as the string."""
    try:
        nums = tuple(float(x) for x in v.split(","))
    except ValueError:
        return v
    return nums if "," in v else nums[0]


def parameter_defaults(cls) -> SimpleNamespace:
    """The keyword defaults of ``cls``'s constructor, for :func:`field_overrides` on a class that is no dataclass."""
    return SimpleNamespace(**{k: p.default for k, p in inspect.signature(cls).parameters.items()
                              if p.default is not inspect.Parameter.empty})
