"""Fixtures of the experiments' tests: a valid results object, fresh for each test."""

from __future__ import annotations

import pytest
from helpers.report_cases import results


@pytest.fixture
def good() -> dict:
    return results()
