"""kernels/native: the C++ of the CPU fast paths as files, and its loader kernels.native.source.

Every file there is used (a .cpp by a `source("name.cpp", ...)` call in a module under kernels/, a .h
by a used .cpp), opens with a comment naming the Python module that uses it, and ships in the wheel;
the loader inlines headers (so Warp's module hash, which hashes the snippet text, follows every file a
kernel includes) and refuses a missing file, a missing parameter and an unknown one in one line; no
Python file under kernels/ holds C++ in a multi-line string any more.
"""

from __future__ import annotations

import ast
import re
import zipfile
from pathlib import Path

import pytest
import warp as wp

from kernels import native
from kernels.native import NativeSourceError, source
from tests.wheel_build import build_wheel, can_build_wheels

REPO = Path(__file__).resolve().parents[2]
KERNELS = REPO / "kernels"


def _python_files() -> list[Path]:
    return sorted(p for p in KERNELS.rglob("*.py") if "__pycache__" not in p.parts)


def _source_calls() -> dict[str, list[tuple[Path, set[str]]]]:
    """file name -> [(Python file, the keyword names passed)] for every `source("name", ...)` call in kernels/."""
    calls: dict[str, list[tuple[Path, set[str]]]] = {}
    for path in _python_files():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "source"
                    and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
                calls.setdefault(node.args[0].value, []).append((path, {k.arg for k in node.keywords}))
    return calls


def test_every_native_file_is_used_and_every_used_file_exists():
    calls = _source_calls()
    names = native.files()
    assert names, "kernels/native holds no C++ files"
    cpps = [n for n in names if n.endswith(".cpp")]
    headers = [n for n in names if n.endswith(".h")]
    assert sorted(calls) == sorted(set(calls) & set(cpps)), f"source() of files that are not .cpp files here: " \
                                                            f"{sorted(set(calls) - set(cpps))}"
    unused = [n for n in cpps if n not in calls]
    assert not unused, f".cpp files no module under kernels/ loads: {unused}"
    included = {h for n in cpps for h in native.includes(n)}
    assert not [h for h in headers if h not in included], \
        f".h files no .cpp includes: {[h for h in headers if h not in included]}"
    # each call passes exactly the file's parameters
    for name, sites in calls.items():
        for path, keys in sites:
            assert keys == set(native.parameters(name)), (path, name, keys, native.parameters(name))


def test_every_native_file_says_which_python_module_uses_it():
    calls = _source_calls()
    for name in native.files():
        lines = (native.DIR / name).read_text().splitlines()
        header = []
        for line in lines:
            if not line.startswith("//"):
                break
            header.append(line)
        assert header, f"{name}: no header comment (which kernel uses it, what it computes)"
        text = " ".join(header)
        modules = set(re.findall(r"kernels/[\w/]+\.py", text))
        assert modules, f"{name}: the header names no Python module (kernels/....py)"
        for m in modules:
            assert (REPO / m).is_file(), f"{name}: its header names {m}, which does not exist"
        users = {str(path.relative_to(REPO)) for path, _ in calls.get(name, [])}
        assert users <= modules, f"{name}: loaded by {sorted(users - modules)}, which its header does not name"


def test_loaded_text_has_headers_inlined_and_no_placeholders_left():
    params = {"composite_forward.cpp": dict(GROUPS=8, RING=2048), "window_lanes.cpp": dict(SIDE=9, LANES=4,
              FROM_PATCH=0), "patch_groups.cpp": dict(SIDE=10, STORE="float", FUSED=1)}
    for name in native.files():
        if not name.endswith(".cpp"):
            continue
        wanted = native.parameters(name)
        given = params.get(name, {k: 3 for k in wanted})
        text = source(name, **given)
        assert "@" not in text, name
        assert '#include "' not in text, name
        assert not text.startswith("//"), f"{name}: the header comment is not dropped"
        for header in native.includes(name):
            body = native._read(header)
            assert body.strip() and body.strip().splitlines()[0] in text, (name, header)


def test_loader_refuses_unknown_and_missing_parameters_and_missing_files():
    with pytest.raises(NativeSourceError, match=r"^kernels/native/window_sample\.cpp: unknown template parameter "
                                                r"RADIUS \(the file's parameters: SIDE\)$"):
        source("window_sample.cpp", SIDE=9, RADIUS=4)
    with pytest.raises(NativeSourceError, match=r"^kernels/native/window_lanes\.cpp: template parameter LANES not "
                                                r"given"):
        source("window_lanes.cpp", SIDE=9, FROM_PATCH=0)
    with pytest.raises(NativeSourceError, match=r"^kernels/native/census_row\.cpp: unknown template parameter SIDE"):
        source("census_row.cpp", SIDE=3)
    with pytest.raises(NativeSourceError, match=r"^kernels/native/no_such_kernel\.cpp: no such file$"):
        source("no_such_kernel.cpp")
    with pytest.raises(NativeSourceError, match=r"not a file name of kernels/native"):
        source("../_arrays.py")
    with pytest.raises(NativeSourceError, match=r"window_sample\.cpp: template parameter SIDE='9\\n': expected"):
        source("window_sample.cpp", SIDE="9\n")
    for call in (lambda: source("window_sample.cpp", SIDE=9, RADIUS=4), lambda: source("no_such_kernel.cpp")):
        with pytest.raises(NativeSourceError) as info:
            call()
        assert "\n" not in str(info.value)


def test_loader_inlines_includes_and_refuses_a_missing_or_circular_one(tmp_path, monkeypatch):
    monkeypatch.setattr(native, "DIR", tmp_path)
    (tmp_path / "a.cpp").write_text("// a: a test file\n// second line\n    int x = @N@;\n#include \"b.h\"\n"
                                    "    return x;\n")
    (tmp_path / "b.h").write_text("// b: a test header\n    x = x + @N@;\n")
    assert source("a.cpp", N=2) == "    int x = 2;\n    x = x + 2;\n    return x;\n"
    assert native.includes("a.cpp") == ["b.h"] and native.parameters("a.cpp") == ["N"]
    (tmp_path / "c.cpp").write_text("// c\n#include \"d.h\"\n")
    with pytest.raises(NativeSourceError, match=r'^kernels/native/c\.cpp: #include "d\.h": no such file'):
        source("c.cpp")
    (tmp_path / "d.h").write_text("// d\n#include \"e.h\"\n")
    (tmp_path / "e.h").write_text("// e\n#include \"d.h\"\n")
    with pytest.raises(NativeSourceError, match=r"includes itself \(c\.cpp -> d\.h -> e\.h -> d\.h\)"):
        source("c.cpp")


def test_a_header_change_changes_the_warp_module_hash(tmp_path, monkeypatch):
    """Warp keys its kernel cache by a hash of the snippet string: the loader inlines headers, so a change
    in a header reaches the hash (an `#include` of a path left to the compiler would not)."""
    monkeypatch.setattr(native, "DIR", tmp_path)
    (tmp_path / "k.cpp").write_text("// k: a test kernel\n#include \"k.h\"\n    return v;\n")
    hashes = []
    for i, body in enumerate(("    const int v = 1;\n", "    const int v = 2;\n")):
        (tmp_path / "k.h").write_text("// k.h\n" + body)

        def stub() -> int: ...

        stub.__name__ = stub.__qualname__ = f"native_hash_probe_{i}"
        func = wp.func_native(source("k.cpp"))(stub)

        def run(out: wp.array(dtype=wp.int32)):
            out[0] = func()

        run.__name__ = run.__qualname__ = "native_hash_probe_kernel"
        kernel = wp.kernel(run, enable_backward=False, module="unique")
        hashes.append(kernel.module.hash_module())
    assert hashes[0] != hashes[1]


# C++ in a Python string: two or more lines ending as statements or blocks do (";", "{", "}") and a C++
# keyword, type or builtin
_CPP = re.compile(r"\b(typedef|const \w+\*? \w+ = |float \w+\[|for \(int|return [^.]*;|reinterpret_cast|"
                  r"__builtin_\w+|auto \w+ = \[)|#if|#pragma")


def _cpp_strings(tree: ast.AST) -> list[int]:
    """Line numbers of string constants that read as C++ (docstrings excepted)."""
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            ends = [line for line in node.value.splitlines() if line.rstrip().endswith((";", "{", "}"))]
            if len(ends) >= 2 and _CPP.search(node.value):
                found.append(node.lineno)
    return found


def test_no_multiline_cpp_string_left_in_python_under_kernels():
    found = [f"{path.relative_to(REPO)}:{line}" for path in _python_files()
             for line in _cpp_strings(ast.parse(path.read_text(), str(path)))]
    assert not found, f"C++ in Python strings (move it to kernels/native): {found}"


def test_the_scan_would_catch_an_old_snippet():
    """The scan above finds C++ strings such as those the modules held before kernels/native, short ones too."""
    tree = ast.parse('A = r"""\n    typedef float v16f __attribute__((ext_vector_type(16)));\n'
                     '    typedef int v16i __attribute__((ext_vector_type(16)));\n"""\n'
                     'B = r"""\n#if defined(__CUDA_ARCH__)\n    return 0;\n#else\n    return 1;\n#endif\n"""\n'
                     'def f():\n    """A docstring that quotes C++: `for (int l = 0; l < 8; ++l) {`;\n    `}`"""\n')
    assert _cpp_strings(tree) == [1, 5]


@pytest.mark.timeout(240)
@pytest.mark.skipif(not can_build_wheels(), reason="no bdist_wheel here (setuptools < 70.1 without `wheel`)")
def test_wheel_carries_every_native_file(tmp_path):
    wheel = build_wheel(REPO, ("kernels",), tmp_path)
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    missing = [n for n in native.files() if f"kernels/native/{n}" not in names]
    assert not missing, f"not in the wheel: {missing}"
