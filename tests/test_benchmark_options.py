"""benchmarks/options.py: FIELD=VALUE overrides typed by the field's default."""

import pytest


def test_values_take_the_type_of_the_default(load_benchmark):
    opt = load_benchmark("options")
    from types import SimpleNamespace

    d = SimpleNamespace(flag=False, n=3, x=0.5, pair=(1.0, 2.0), name="a", loose=None, mode=None, level=None)
    got = opt.field_overrides(d, ["flag=yes", "n=7", "x=0.85", "pair=3,4", "name=b", "loose=-1,0,-1,0",
                                  "mode=spread", "level=0.4"])
    assert got == {"flag": True, "n": 7, "x": 0.85, "pair": (3.0, 4.0), "name": "b",
                   "loose": (-1.0, 0.0, -1.0, 0.0), "mode": "spread", "level": 0.4}


def test_an_unknown_field_is_refused(load_benchmark):
    opt = load_benchmark("options")
    from types import SimpleNamespace

    with pytest.raises(SystemExit, match="no field 'nope'"):
        opt.field_overrides(SimpleNamespace(a=1), ["nope=2"], "Thing")
