"""floaff_zoo.checks: the finite-number and integer argument checks every constructor shares."""

from __future__ import annotations

import math
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest

from floaff_zoo.checks import check_flag, check_integer, check_number, check_numbers, is_number, shown


class OwnError(ValueError):
    """Stands for a module's own configuration error (DataConfigError, MisconfigurationException)."""


@pytest.mark.parametrize(
    "value", [0, 0.0, 1, 2.5, np.float32(0.5), np.float64(3.0), np.int64(4), Fraction(1, 3), 10**6]
)
def test_finite_numbers_in_range_pass(value):
    check_number("x", value)
    assert is_number(value)


@pytest.mark.parametrize(
    ("value", "got"),
    [
        (True, "True"),  # an int to Python, never a size here
        (False, "False"),
        (np.bool_(True), repr(np.bool_(True))),  # not a number to numpy either
        (None, "None"),
        ("1.0", "'1.0'"),  # a text is shown in quotes
        ([1.0], "[1.0]"),
        (float("nan"), "nan"),
        (float("inf"), "inf"),
        (-math.inf, "-inf"),
        (np.float64("nan"), "nan"),  # numpy's scalars shown as numbers, not as np.float64(nan)
        (10**400, str(10**400)),  # no float holds it
    ],
)
def test_non_numbers_and_non_finite_numbers_are_refused_by_name(value, got):
    with pytest.raises(OwnError) as err:
        check_number("weight", value, owner="Model", error=OwnError)
    assert str(err.value) == f"Model: weight must be a finite number >= 0, got {got}"


def test_the_bounds_are_checked_and_written():
    check_number("w", 0.0)
    with pytest.raises(ValueError, match=r"^w must be a finite number > 0, got 0.0$"):
        check_number("w", 0.0, strict=True)
    with pytest.raises(ValueError, match=r"^w must be a finite number >= 0, got -1e-09$"):
        check_number("w", -1e-9)
    check_number("a", 1.0, high=1.0)
    with pytest.raises(ValueError, match=r"^a must be a finite number >= 0 and <= 1, got 1.5$"):
        check_number("a", 1.5, high=1.0)
    check_number("z", -5.0, low=-math.inf)  # an infinite bound is not checked, nor written
    with pytest.raises(ValueError, match=r"^z must be a finite number, got nan$"):
        check_number("z", float("nan"), low=-math.inf)
    with pytest.raises(ValueError, match=r"^z must be a finite number <= 2.5, got 3$"):
        check_number("z", 3, low=-math.inf, high=2.5)


def test_none_is_accepted_only_where_it_means_something_and_the_note_is_written():
    check_number("clip", None, none_means="no clipping")
    with pytest.raises(ValueError, match=r"^clip must be a finite number > 0 or null \(no clipping\), got -1$"):
        check_number("clip", -1, strict=True, none_means="no clipping")
    with pytest.raises(ValueError, match=r"^O: r must be a finite number > 0 \(0 = off\), got None$"):
        check_number("r", None, strict=True, owner="O", note="0 = off")


def test_check_numbers_names_the_first_bad_one():
    check_numbers({"a": 1.0, "b": 2})
    with pytest.raises(OwnError, match=r"^O: b must be a finite number > 0, got 0$"):
        check_numbers({"a": 1.0, "b": 0, "c": float("nan")}, strict=True, owner="O", error=OwnError)


@pytest.mark.parametrize("value", [0, 3, np.int32(2), np.int64(7), 2**70])
def test_integers_in_range_pass(value):
    check_integer("n", value)


@pytest.mark.parametrize(
    ("value", "got"),
    [
        (-1, "-1"),
        (np.int64(-1), "-1"),
        (2.0, "2.0"),  # a float, even a whole one: a slice index or a size fails on it later
        (2.5, "2.5"),
        (float("nan"), "nan"),
        (True, "True"),
        (None, "None"),
        ("3", "'3'"),
    ],
)
def test_integer_check_refuses_the_rest_by_name(value, got):
    with pytest.raises(OwnError) as err:
        check_integer("data.n", value, error=OwnError)
    assert str(err.value) == f"data.n must be an integer >= 0, got {got}"


def test_integer_bounds_none_and_owner():
    check_integer("seed", 2**32 - 1, 0, 2**32 - 1)
    with pytest.raises(ValueError, match=r"^seed must be an integer >= 0 and <= 4294967295, got 4294967296$"):
        check_integer("seed", 2**32, 0, 2**32 - 1)
    check_integer("k", None, 1, none_means="all")
    with pytest.raises(ValueError, match=r"^O: k must be an integer >= 1 or null \(all\), got 0$"):
        check_integer("k", 0, 1, owner="O", none_means="all")


def test_flags_are_bools_python_or_numpy():
    """One check of a true/false setting where four were spelled (data, rollout callback, presets, curriculum)."""
    for ok in (True, False, np.bool_(True)):
        check_flag("f", ok)
    for bad in ("false", 0, 1, None, np.int64(1), 1.0):
        with pytest.raises(KeyError, match="own: f must be true or false, got"):
            check_flag("f", bad, owner="own", error=KeyError)


def test_shown():
    assert [shown(v) for v in (1, 1.5, np.float32(0.5), "a", None)] == ["1", "1.5", "0.5", "'a'", "None"]


def test_the_module_imports_only_the_standard_library():
    """floaff_zoo.sim uses it, and must import neither torch nor Lightning (nor numpy for this)."""
    code = (
        "import sys, importlib.util\n"
        "spec = importlib.util.spec_from_file_location('checks', sys.argv[1])\n"
        "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
        "print(sorted(k for k in ('numpy', 'torch', 'lightning') if k in sys.modules))\n"
    )
    import floaff_zoo.checks

    out = subprocess.run(
        [sys.executable, "-c", code, floaff_zoo.checks.__file__], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"
