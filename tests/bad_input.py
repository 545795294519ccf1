"""The checks the bad-input tests share: a call refused with one ValueError of one line, and the kernel
launches a refused call made before it raised."""

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


def launches_before_refusal(call: Callable[[], Any], pattern: str, monkeypatch: pytest.MonkeyPatch) -> list:
    """`call()` raises ValueError matching `pattern` (pytest.raises(match=...)); returns the Warp kernel
    launches (wp.launch's positional arguments) it made before raising, an empty list when it was
    refused before any kernel ran."""
    import warp as wp

    launched: list = []
    real = wp.launch
    monkeypatch.setattr(wp, "launch", lambda *a, **k: launched.append(a) or real(*a, **k))
    with pytest.raises(ValueError, match=pattern):
        call()
    return launched
