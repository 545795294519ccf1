"""Building drlab wheels in tests: whether this environment can (the wheel tests of test_native_sources
and test_experiments skip without it), and the build itself."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path


def can_build_wheels() -> bool:
    """setuptools >= 70.1 builds wheels itself; older ones need the `wheel` distribution's bdist_wheel."""
    try:
        import setuptools
    except ImportError:
        return False
    if tuple(int(x) for x in setuptools.__version__.split(".")[:2]) >= (70, 1):
        return True
    from importlib.metadata import entry_points  # the `wheel` distribution registers bdist_wheel

    return any(ep.name == "bdist_wheel" for ep in entry_points(group="distutils.commands"))


def build_wheel(repo: Path, packages: tuple[str, ...], tmp_path: Path) -> Path:
    """A wheel of drlab built (no dependencies, no index) from a copy of `packages` of the checkout `repo`
    with its pyproject.toml and README.md; the path of the .whl file under tmp_path/dist."""
    src = tmp_path / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in packages:
        shutil.copytree(repo / name, src / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(repo / name, src / name)
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
                        "-q", "-w", str(tmp_path / "dist"), str(src)], capture_output=True, text=True, timeout=200)
    assert r.returncode == 0, r.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("drlab-*.whl")
    return wheel
