"""Every Warp module of drlab compiles for CUDA, sm_80 and sm_90, with no GPU (kernels.cuda_build).

sm_80 is compiled to cubins (NVRTC and ptxas, the whole route); sm_90 to PTX for compute_90, which
runs NVRTC's front end and optimiser for that architecture and leaves ptxas, already exercised by
the sm_80 cubins, to the driver at load: half the time of a second cubin build (about 25 s of a
2-core machine's ~50 s), for the same check of the source.

Warp's NVRTC is linked into its library, so `wp.compile_aot_module(module, arch=...)` builds CUDA
binaries on a machine without a GPU or driver. The modules come from `cuda_build.project_modules()`
(the whole `kernels` package, the kernels its factories build on first use, and the research
modules that define kernels, imported here); the modules in `cuda_build.CPU_ONLY` are CPU-only by
design and must fail for CUDA, so the list cannot go stale. The compile tests skip only where this
Warp build has no CUDA compiler at all.
"""

from __future__ import annotations

import ast
import importlib
import pathlib

import pytest
import warp as wp

from kernels import cuda_build

ROOT = pathlib.Path(__file__).resolve().parents[2]
ARCHS = (80, 90)


def _defines_kernel(tree: ast.AST) -> list[tuple[str, bool]]:
    """(function name, nested in another function) of every `@wp.kernel` function in a module's AST."""
    found = []

    def visit(node: ast.AST, nested: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for dec in child.decorator_list:
                    target = dec.func if isinstance(dec, ast.Call) else dec
                    if isinstance(target, ast.Attribute) and target.attr == "kernel":
                        found.append((child.name, nested))
                visit(child, True)
            else:
                visit(child, nested)

    visit(tree, False)
    return found


def _kernel_sources() -> dict[str, list[tuple[str, bool]]]:
    """{Python module: its @wp.kernel functions} for every drlab module that defines one."""
    out = {}
    for package in ("kernels", "research", "experiments"):
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            if "wp.kernel" not in text:
                continue
            kernels = _defines_kernel(ast.parse(text))
            if kernels:
                parts = path.relative_to(ROOT).with_suffix("").parts
                out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = kernels
    return out


@pytest.fixture(scope="module")
def sources() -> dict[str, list[tuple[str, bool]]]:
    return _kernel_sources()


@pytest.fixture(scope="module")
def modules(sources):
    # kernels never imports research: the research modules that define kernels are imported here
    for name in sources:
        if not name.startswith("kernels."):
            importlib.import_module(name)
    return cuda_build.project_modules()


@pytest.fixture(scope="module")
def labels(modules) -> list[str]:
    return [cuda_build.module_label(m) for m in modules]


def _require_nvrtc() -> None:
    if not cuda_build.nvrtc_archs():
        pytest.skip("this Warp build reports no CUDA compilation (CUDA not enabled or no NVRTC architectures)")


def test_every_module_that_defines_a_kernel_is_found(sources, labels):
    found = set(labels)
    for module, kernels in sources.items():
        assert module in found or any(label.startswith(module + ".") for label in found), module
        # a kernel defined inside a function comes from a factory: cuda_build must call it
        for name, nested in kernels:
            if nested:
                assert f"{module}.{name}" in found, (
                    f"{module}.{name} is built by a factory that kernels.cuda_build._factories does not call")


def test_discovery_is_not_suspiciously_small(labels):
    found = set(labels)
    for family in ("kernels.volume.", "kernels.corr.", "kernels.splat.", "kernels.stereo.", "kernels.points."):
        assert sum(label.startswith(family) for label in found) >= 3, family
    for single in ("kernels.lucas_kanade", "kernels.ssim", "kernels.optim", "kernels.ba", "research.bench.launch"):
        assert single in found
    # the lazily built kernels: one module per factory argument set
    n_corr = len(cuda_build.CORR_RADII)
    expected = {
        "kernels.stereo.census.census": len(cuda_build.CENSUS_RADII),
        "kernels.volume.hashgrid_cpu.hash_forward_cpu": 2,
        "kernels.volume.hashgrid_cpu.hash_backward_cpu": 2,
        "kernels.corr.window_cpu.sample_levels_cpu": 2 * n_corr,
        "kernels.corr.window_cpu.sample_patches_cpu": 2 * n_corr,
        "kernels.corr.patch_cpu.group_pixels_cpu": 2 * n_corr,
        "kernels.corr.patch_cpu.patch_groups_cpu": 3 * n_corr,  # float32, float32 over float16, float64
        "kernels.corr.patch_cpu.widen_rows_cpu": 1,
        "kernels.volume.composite_cpu.composite_forward_cpu": 1,
        "kernels.volume.composite_cpu.composite_backward_cpu": 1,
        "kernels.volume.spheres_cpu.spheres_render_dense8_cpu": 1,
        "kernels._npexp.npexp16_array": 1,
    }
    for label, count in expected.items():
        # at least: the rest of a test session may have built more (other radii)
        assert labels.count(label) >= count, (label, labels.count(label))
    assert len(labels) >= 60


def test_cpu_only_entries_name_existing_modules(labels):
    for key, reason in cuda_build.CPU_ONLY.items():
        assert reason.strip(), key
        assert any(label == key or label.startswith(key + ".") for label in labels), f"CPU_ONLY entry {key} is stale"


def test_cpu_only_modules_do_not_compile_for_cuda(modules, tmp_path):
    # if one of them compiles, it is not CPU-only any more: take it off the list, so the test compiles it
    _require_nvrtc()
    cpu_only = [m for m in modules if cuda_build.cpu_only_reason(cuda_build.module_label(m)) is not None]
    assert cpu_only
    for m in cpu_only:
        with pytest.raises(Exception, match="CUDA kernel build failed"):
            wp.compile_aot_module(m, arch=ARCHS[0], module_dir=str(tmp_path))


@pytest.mark.parametrize("arch,use_ptx", [(80, False), (90, True)])
def test_every_other_module_compiles_for_cuda(modules, arch, use_ptx, tmp_path):
    _require_nvrtc()
    results = cuda_build.compile_all(arch, tmp_path, modules, use_ptx=use_ptx)
    failed = [f"{r.name} ({r.module}): {r.error}" for r in results if not r.ok]
    assert not failed, "\n".join(failed)
    assert len(results) == sum(cuda_build.cpu_only_reason(label) is None for label in
                               (cuda_build.module_label(m) for m in modules))
    suffix = "ptx" if use_ptx else "cubin"
    assert len(list(tmp_path.glob(f"*.sm{arch}.{suffix}"))) == len(results)
