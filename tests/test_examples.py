"""Every script in docs/examples/ runs to completion and prints what it promises.

Each example runs in its own Python process, as a reader would run it, with the repository root
first on PYTHONPATH (so this checkout's code is imported, not another installed copy) and a
timeout. A script fails by a non-zero exit status or by missing its expected last line.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "docs" / "examples"

# Script -> a line it prints only after its own checks passed.
EXPECTED = {
    "render_splats.py": "gradient step lowered the loss",
    "composite_rays.py": "backward matches the finite difference",
    "gradcheck_own_kernel.py": "hand-written backward passes; the wrong one is caught",
}
TIMEOUT_S = 180  # a cold Warp kernel cache compiles each kernel module first (seconds each on 2 cores)


def run_example(name: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    return subprocess.run([sys.executable, str(EXAMPLES / name)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=TIMEOUT_S)


def test_every_example_is_listed():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_example_runs(name):
    proc = run_example(name)
    output = f"--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}"
    assert proc.returncode == 0, f"{name} exited with {proc.returncode}\n{output}"
    assert EXPECTED[name] in proc.stdout.splitlines(), f"{name} did not print {EXPECTED[name]!r}\n{output}"
