"""The page's columns (report/traces.nums) as the page's script writes them: a rounded float64 array, whose bytes in
the script are those of the list of its values with null for NaN, the infinities null too."""

from __future__ import annotations

import math

import numpy as np
import orjson
import pytest

from slipdaq.report.page_data import script
from slipdaq.report.traces import line, nums

VALUES = [0.0, -0.0, 1e-5, 9.99e-5, 1e-4, 0.1, 2.5, -3.14159265, 123456789.123456, 1e16, 1e21, 1e22, 5e-324, 1e-7,
          1.7976931348623157e308, math.nan, math.inf, -math.inf, None, 12345678901234567.0]


def as_list(values: list[float | None], digits: int) -> list[float | None]:
    """The column as a list: the values rounded by numpy, None for NaN (what json.dumps would need)."""
    rounded = np.round(np.asarray(values, dtype=np.float64), digits).tolist()
    return [None if v != v else v for v in rounded]


@pytest.mark.parametrize("digits", [0, 1, 2, 3, 4, 6])
def test_a_column_writes_as_its_list(digits: int) -> None:
    rng = np.random.default_rng(digits)
    values = VALUES + rng.uniform(-1000.0, 1000.0, 5000).tolist() + rng.normal(0.0, 1e-3, 2000).tolist()
    with np.errstate(over="ignore"):
        column = nums(values, digits)
        expected = as_list(values, digits)
    assert column.dtype == np.float64
    assert orjson.dumps(column, option=orjson.OPT_SERIALIZE_NUMPY) == orjson.dumps(expected)
    read = orjson.loads(orjson.dumps(column, option=orjson.OPT_SERIALIZE_NUMPY))
    assert read == [None if v is None or math.isinf(v) else v for v in expected]  # the infinities: null too


def test_a_figure_in_the_script_is_the_same_bytes_as_with_lists() -> None:
    t = np.linspace(0.0, 1.0, 7)
    y = np.array([1.23456, math.nan, -0.0, 2.0, math.inf, 1e-5, 3.0])
    trace = line(t, y, name="FL", color="#000")
    as_lists = trace | {"x": as_list(t.tolist(), 3), "y": as_list(y.tolist(), 3)}
    figure = {"data": [trace], "layout": {}}
    assert script({"p": figure}) == b"slipdaqReport.add(" + orjson.dumps({"p": {"data": [as_lists], "layout": {}}}) \
        + b");\n"
    assert orjson.loads(script({"p": figure})[len(b"slipdaqReport.add("):-3])["p"]["data"][0]["y"] == \
        [1.235, None, -0.0, 2.0, None, 0.0, 3.0]
