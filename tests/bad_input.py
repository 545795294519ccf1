"""The check the bad-input tests share: a call refused with one ValueError of one line."""

from __future__ import annotations

import re
from typing import Any, Callable

import pytest


def assert_refused(call: Callable[[], Any], pattern: str) -> None:
    """`call()` raises ValueError whose message is one line and matches `pattern` (re.search)."""
    with pytest.raises(ValueError) as err:
        call()
    assert "\n" not in str(err.value)
    assert re.search(pattern, str(err.value)), str(err.value)
