"""One reading of a number from results (``finite_number``) and one way of writing it into a page
(``number_text``), shared by the report, the comparison and the intervals."""

from __future__ import annotations

import math

import pytest

from replaybench.report.markup import escaped, number_text
from replaybench.results.numbers import finite_number


@pytest.mark.parametrize(
    ('value', 'expected'),
    [(3, 3.0), (2.5, 2.5), (-0.0, -0.0), (True, None), (False, None), (None, None), ('1.5', None)],
)
def test_a_finite_int_or_float_reads_as_a_float_and_anything_else_as_none(value, expected):
    number = finite_number(value)
    assert number == expected
    assert number is None or type(number) is float


@pytest.mark.parametrize('value', [math.nan, math.inf, -math.inf])
def test_a_number_that_is_not_finite_reads_as_none(value):
    assert finite_number(value) is None


def test_number_text_writes_by_its_format_spec_and_a_missing_or_infinite_value_as_missing():
    assert number_text(0.123456, '.4g') == '0.1235'
    assert number_text(2.0, '.2f') == '2.00'
    assert number_text(None, '.2f') == '–'
    assert number_text(math.nan, '.2f', '-') == '-'
    assert number_text(math.inf, '.4g') == '–'


def test_escaped_text_holds_no_markup_and_no_control_character():
    assert escaped('<b a="1">\x1b[2J') == '&lt;b a=&quot;1&quot;&gt;\\x1b[2J'
