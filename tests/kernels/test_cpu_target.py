"""kernels.cpu_target: DRLAB_CPU_TARGET swaps Warp's host-CPU flag for clang's -target-cpu."""

from __future__ import annotations

import pytest

from kernels import cpu_target

WARP_DEFAULT = ("-march=native -mllvm=-inline-threshold=9000 -mllvm=-inline-cold-callsite-threshold=3000"
                " -mllvm=-slp-recursion-max-depth=4")


def test_target_replaces_march_native_and_keeps_the_other_flags():
    out = cpu_target.flags_for("znver3", WARP_DEFAULT)
    assert out.split()[:2] == ["-target-cpu", "znver3"] and "-march=native" not in out
    assert out.split()[2:] == WARP_DEFAULT.split()[1:]
    # applied twice, or over Warp's None default: one target, the last one named
    assert cpu_target.flags_for("haswell", out).split() == ["-target-cpu", "haswell", *WARP_DEFAULT.split()[1:]]
    assert cpu_target.flags_for("haswell", None) == "-target-cpu haswell"


def test_environment_names_the_cpu_or_is_refused(monkeypatch):
    monkeypatch.delenv(cpu_target.ENV, raising=False)
    assert cpu_target.requested() is None
    monkeypatch.setenv(cpu_target.ENV, " x86-64-v3 ")
    assert cpu_target.requested() == "x86-64-v3"
    monkeypatch.setenv(cpu_target.ENV, "znver3 -O0")
    with pytest.raises(ValueError, match="DRLAB_CPU_TARGET: expected an LLVM CPU name"):
        cpu_target.requested()


def test_apply_sets_warps_flags_only_when_asked(monkeypatch):
    import warp as wp

    monkeypatch.setattr(wp.config, "cpu_compiler_flags", WARP_DEFAULT)
    monkeypatch.delenv(cpu_target.ENV, raising=False)
    assert cpu_target.apply() is None and wp.config.cpu_compiler_flags == WARP_DEFAULT
    monkeypatch.setenv(cpu_target.ENV, "znver3")
    assert cpu_target.apply() == "znver3"
    assert wp.config.cpu_compiler_flags.startswith("-target-cpu znver3 ")


def test_module_flags_name_the_same_cpu(monkeypatch):
    monkeypatch.delenv(cpu_target.ENV, raising=False)
    assert cpu_target.module_flags("-mllvm=-inline-threshold=9000") == "-march=native -mllvm=-inline-threshold=9000"
    monkeypatch.setenv(cpu_target.ENV, "znver3")
    assert cpu_target.module_flags("-O3") == "-target-cpu znver3 -O3"
    assert cpu_target.module_flags() == "-target-cpu znver3"
