"""research.results: the host record that timings and dataset hashes are read against."""

from __future__ import annotations

from research.results import host

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 26
model\t\t: 2
model name\t: AMD EPYC
flags\t\t: fpu sse sse2 avx avx2 fma avx512f avx512bw

processor\t: 1
vendor_id\t: AuthenticAMD
cpu family\t: 26
model\t\t: 2
model name\t: AMD EPYC
flags\t\t: fpu sse sse2 avx avx2 fma avx512f avx512bw
"""


def test_host_reads_model_family_and_widest_simd(tmp_path):
    path = tmp_path / "cpuinfo"
    path.write_text(CPUINFO)
    h = host(path)
    assert h["cpu"] == "AMD EPYC (cpu family 26, model 2)"  # the first processor's, once
    assert h["simd"] == "avx512f" and h["cpus"] >= 1
    path.write_text(CPUINFO.replace(" avx512f avx512bw", ""))
    assert host(path)["simd"] == "avx2"


def test_host_without_cpuinfo_still_names_the_machine(tmp_path):
    h = host(tmp_path / "missing")
    assert h["cpu"] and h["simd"] == "unknown" and h["cpus"] >= 1
