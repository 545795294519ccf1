"""Shared pieces of the CPU kernels written in C++ through wp.func_native (corr, hash grid,
compositing, spheres, splat rows): the build-once cache (each native kernel is built on first use,
once per key, even when launch threads ask for it at the same time) and C++ snippet text."""

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


# sel(m, a, b): lane by lane a where the mask m (an integer vector of all-ones / all-zeros lanes) is set, else
# b, by the bits (no arithmetic, so no rounding); a and b of one clang vector type, m of the integer vector type
# of its width. Paste into a func_native body before the first use.
SELECT_CPP = r"""
    auto sel = [](auto m, auto a, auto b) __attribute__((always_inline)) {
        typedef decltype(m) I;
        typedef decltype(a) F;
        return __builtin_bit_cast(F, (m & __builtin_bit_cast(I, a)) | (~m & __builtin_bit_cast(I, b)));
    };
"""
