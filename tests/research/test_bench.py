"""The bench infrastructure: interleaved medians and `--compare` routing (research.bench)."""

import sys
import types

import pytest

from research.bench import accepts_compare, run_bench, time_medians


def _install_family(monkeypatch, name: str, cases) -> None:
    mod = types.ModuleType(f"_fake_bench_{name}")
    mod.cases = cases
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    from research import registry

    monkeypatch.setitem(registry.FAMILIES, name, registry.Family(name, "a fake bench family", bench=mod.__name__))


def test_compare_is_passed_only_to_families_that_accept_it(monkeypatch):
    seen = {}

    def with_compare(device="cpu", quick=False, tiny=False, compare=False):
        seen["with"] = compare
        yield {"bench": "fa.x", "device": device, "threads": 1, "t_s": 1.0}

    def without_compare(device="cpu", quick=False, tiny=False):
        seen["without"] = "called"
        yield {"bench": "fb.x", "device": device, "threads": 1, "t_s": 1.0}

    _install_family(monkeypatch, "fa", with_compare)
    _install_family(monkeypatch, "fb", without_compare)
    rows = run_bench(["fa", "fb"], "cpu", quick=True, compare=True)
    assert seen == {"with": True, "without": "called"}
    assert [r["bench"] for r in rows] == ["fa.x", "fb.x"] and all("cpu" in r for r in rows)
    seen.clear()
    run_bench(["fa"], "cpu", quick=True)
    assert seen == {"with": False}


@pytest.mark.parametrize("fn, expected", [
    (lambda device, quick, tiny=False, compare=False: None, True),
    (lambda device, quick, tiny=False: None, False),
    (lambda device, quick, **kw: None, True),
], ids=["keyword", "absent", "var_keyword"])
def test_accepts_compare(fn, expected):
    assert accepts_compare(fn) is expected


def test_time_medians_interleaves():
    order = []
    time_medians({"a": lambda: order.append("a"), "b": lambda: order.append("b")}, repeats=3, warmup=1)
    assert order == ["a", "b"] * 4


def test_time_medians_settles_before_each_timed_run_only(monkeypatch):
    import research.bench as bench

    events = []
    monkeypatch.setattr(bench.time, "sleep", lambda s: events.append(("sleep", s)))
    time_medians({"a": lambda: events.append("a"), "b": lambda: events.append("b")}, repeats=3, warmup=1,
                 settle_s=0.02)
    # warm-up runs without idling; every timed run follows one idle of settle_s
    assert events == ["a", "b"] + [("sleep", 0.02), "a", ("sleep", 0.02), "b"] * 3
    events.clear()
    time_medians({"a": lambda: events.append("a")}, repeats=3)
    assert events == ["a"] * 4


def test_cli_bench_help_documents_compare():
    from research.cli import build_parser

    p = build_parser()
    sub = next(a for a in p._subparsers._group_actions if a.dest)  # the subcommand action
    assert "--compare" in sub.choices["bench"].format_help()


def test_volume_compare_rows_carry_reference_or_ref_missing():
    import importlib.util

    from research.bench import volume

    rows = {r["bench"]: r for r in volume.cases("cpu", quick=True, tiny=True, compare=True)
            if not r["bench"].startswith("volume.field")}
    have_torch = importlib.util.find_spec("torch") is not None
    for name, phases in (("volume.composite", ("fwd", "fwd_bwd")), ("volume.composite_fwd", ("fwd",))):
        row = rows[name]
        if have_torch:
            assert row["ref"].startswith("torch") and "ref_missing" not in row
            for p in phases:
                assert row[f"ref_{p}_s"] > 0 and row[f"speedup_{p}"] == row[f"ref_{p}_s"] / row[f"{p}_s"]
        else:
            assert "torch" in row["ref_missing"] and not any(k.startswith(("ref_", "speedup_")) and k != "ref_missing"
                                                             for k in row)
    assert rows["volume.composite"]["bound_s"] > 0
    comp = rows["volume.composite"]
    assert comp["bound_max_s"] > 0 and comp["fwd_over_bound_max"] == comp["fwd_s"] / comp["bound_max_s"]
    assert comp["fwd_no_factor_s"] > 0
    assert comp["fwd_no_factor_over_bound_max"] == comp["fwd_no_factor_s"] / comp["bound_max_s"]
    assert rows["volume.composite_fwd"]["fwd_no_factor_s"] > 0
    sph = rows["volume.spheres_render"]
    for phase in ("render", "render_fused"):
        assert sph[f"speedup_{phase}"] == sph[f"ref_{phase}_s"] / sph[f"{phase}_s"]


def test_performance_refresh_readme_replaces_only_between_markers(tmp_path):
    from experiments.performance import README_END, README_START, refresh_readme

    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n{README_START}\nold table\n{README_END}\nafter\n")
    assert "refreshed" in refresh_readme(readme, "| a |\n|---|\n| 1 |\n")
    assert readme.read_text() == f"# x\n\nbefore\n{README_START}\n| a |\n|---|\n| 1 |\n{README_END}\nafter\n"
    plain = tmp_path / "PLAIN.md"
    plain.write_text("no markers\n")
    assert "not changed" in refresh_readme(plain, "| a |")
    assert plain.read_text() == "no markers\n"
