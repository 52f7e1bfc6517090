"""The package's module examples run as written (the numbers they print are checked)."""

import doctest

import pytest

from ftafm import bimodal, fm


@pytest.mark.parametrize("module", [bimodal, fm])
def test_module_examples(module: object) -> None:
    result = doctest.testmod(module)  # type: ignore[arg-type]
    assert result.attempted > 0
    assert result.failed == 0
