"""Build-once caches for the CPU kernels written in C++ through wp.func_native (corr, hash grid,
compositing): each native kernel is built on first use, once per key, even when launch threads ask
for it at the same time."""

from __future__ import annotations

import threading
from typing import Any, Callable

# Re-entrant: a build may ask for another cached piece (a corr kernel asks for its window function).
_lock = threading.RLock()


def built_once(cache: dict, key: Any, build: Callable[[], Any]) -> Any:
    """cache[key], made by build() on first use: one build per key even when threads ask at once."""
    with _lock:
        value = cache.get(key)
        if value is None:
            value = cache[key] = build()
    return value
