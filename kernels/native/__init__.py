"""The C++ of drlab's CPU fast paths, as files, and the one helper that loads them.

Every `wp.func_native` snippet of the `kernels` package lives in this folder: a `.cpp` file is the
body of one native function (what `source(name)` returns for `wp.func_native`), a `.h` file a piece
shared by several of them (the lane helpers `lanes.h`, the compositing step `blend8.h`, the exps
`npexp16.h` / `vexp16.h`, ...), pulled in by a line `#include "name.h"`. Each file opens with `//`
comment lines saying which Python kernel uses it and what maths it implements; docs/warp.md lists
the files and what each relies on in Warp, clang and NumPy.

`source(name, **params)` returns the text Warp compiles:

  * the file's leading `//` comment lines are dropped (so a comment change alone does not rebuild);
  * each line `#include "x.h"` is replaced by x.h's text (recursively, header comment dropped too).
    The loader inlines it because Warp hashes the snippet *string* into the module hash that keys
    its kernel cache: a real `#include` of a path would leave the hash, and so the cached binary,
    unchanged when the header changes. The text returned is everything compiled, so a change to
    any file it includes rebuilds the kernels that use it;
  * each template parameter `@NAME@` (upper-case name between two `@`) is replaced by the value
    passed as NAME=...: an int (bool: 1 / 0) or a one-line string such as a C type name. Every
    placeholder must get a value and every value must have a placeholder, else NativeSourceError,
    one line naming the file and the parameter. Parameters are for constants and type names; a
    choice between code paths is made in the file with `#if @FLAG@` ... `#else` ... `#endif`.

`built_once(cache, key, build)` is the cache every factory of a native kernel uses: one build per
key even when launch threads ask for it at the same time. `native_flag(probe)` runs a fast path's
`*_available.cpp` probe (1 where its C++ was compiled to do its work) in a CPU kernel.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any, Callable

import warp as wp

DIR = Path(__file__).resolve().parent
_PLACEHOLDER = re.compile(r"@([A-Z][A-Z0-9_]*)@")
_INCLUDE = re.compile(r'^#include[ \t]+"([^"]*)"[ \t]*$')
_NAME = re.compile(r"[A-Za-z0-9_]+\.(cpp|h)")


class NativeSourceError(ValueError):
    """A C++ file of kernels/native that is missing, or whose template parameters do not match."""


def files() -> list[str]:
    """The names of the C++ files in kernels/native (.cpp and .h), sorted."""
    return sorted(p.name for p in DIR.iterdir() if p.is_file() and _NAME.fullmatch(p.name))


def _where(name: str) -> str:
    return f"kernels/native/{name}"


def _read(name: str, included_from: str | None = None) -> str:
    """The file's text less its leading `//` comment lines."""
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        what = f"{_where(included_from)}: #include {name!r}" if included_from else f"{name!r}"
        raise NativeSourceError(f"{what}: not a file name of kernels/native (expected NAME.cpp or NAME.h)")
    path = DIR / name
    if not path.is_file():
        if included_from is not None:
            raise NativeSourceError(f"{_where(included_from)}: #include \"{name}\": no such file {_where(name)}")
        raise NativeSourceError(f"{_where(name)}: no such file")
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    k = 0
    while k < len(lines) and lines[k].startswith("//"):
        k += 1
    return "".join(lines[k:])


def _expand(name: str, stack: tuple[str, ...], included_from: str | None = None) -> str:
    if name in stack:
        raise NativeSourceError(f"{_where(stack[-1])}: #include \"{name}\" includes itself "
                                f"({' -> '.join(stack + (name,))})")
    text = _read(name, included_from)
    out = []
    for line in text.splitlines(keepends=True):
        m = _INCLUDE.match(line.rstrip("\n"))
        if m is None:
            out.append(line)
        else:
            out.append(_expand(m.group(1), stack + (name,), name))
    return "".join(out)


def includes(name: str) -> list[str]:
    """The .h files `name` includes, directly or through other headers, in order of first inclusion."""
    seen: list[str] = []

    def walk(n: str, stack: tuple[str, ...]) -> None:
        for line in _read(n).splitlines():
            m = _INCLUDE.match(line)
            if m is not None and m.group(1) not in stack:
                if m.group(1) not in seen:
                    seen.append(m.group(1))
                walk(m.group(1), stack + (n,))

    walk(name, ())
    return seen


def parameters(name: str) -> list[str]:
    """The template parameters (@NAME@) of a file and the headers it includes, sorted."""
    return sorted(set(_PLACEHOLDER.findall(_expand(name, ()))))


def _value(name: str, key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str) and value and "\n" not in value and "@" not in value:
        return value
    raise NativeSourceError(f"{_where(name)}: template parameter {key}={value!r}: expected an int, a bool or "
                            "a one-line string")


def source(name: str, **params: Any) -> str:
    """The C++ of kernels/native/`name` for wp.func_native: header comment dropped, headers inlined,
    each @NAME@ replaced by params[NAME] (module docstring). NativeSourceError if the file is missing,
    a placeholder has no value or a value has no placeholder."""
    text = _expand(name, ())
    wanted = set(_PLACEHOLDER.findall(text))
    unknown = sorted(set(params) - wanted)
    if unknown:
        have = ", ".join(sorted(wanted)) or "none"
        raise NativeSourceError(f"{_where(name)}: unknown template parameter {unknown[0]} (the file's parameters: "
                                f"{have})")
    missing = sorted(wanted - set(params))
    if missing:
        raise NativeSourceError(f"{_where(name)}: template parameter {missing[0]} not given (@{missing[0]}@ "
                                "needs a value)")
    values = {key: _value(name, key, value) for key, value in params.items()}
    return _PLACEHOLDER.sub(lambda m: values[m.group(1)], text)


# Re-entrant: a build may ask for another cached piece (a corr kernel asks for its window function).
_lock = threading.RLock()


def built_once(cache: dict, key: Any, build: Callable[[], Any]) -> Any:
    """cache[key], made by build() on first use: one build per key even when threads ask at once."""
    with _lock:
        value = cache.get(key)
        if value is None:
            value = cache[key] = build()
    return value


def native_flag(probe: Callable[[], int]) -> int:
    """What `probe`, a `wp.func_native` of no arguments returning an int (a `*_available.cpp` file), returns
    in a CPU kernel compiled with the CPU flags every kernel gets (each call launches one kernel)."""
    @wp.kernel(enable_backward=False, module="unique")
    def native_flag_kernel(out: wp.array(dtype=wp.int32)):
        out[0] = probe()

    out = wp.zeros(1, dtype=wp.int32, device="cpu")
    wp.launch(native_flag_kernel, 1, [out], device="cpu")
    return int(out.numpy()[0])
