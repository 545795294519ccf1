"""Shared pytest set-up: the devices the device-parametrised tests run on, and the tests of the CPU
fast paths.

A test marked `@pytest.mark.cpu_fast_path` tests a CPU fast path itself (that it gives the plain Warp
kernel's bits, that it ran, its memory accounting): it is skipped while the fast paths are off
(DRLAB_FAST_PATHS=0, kernels.fast_paths), when the CPU runs the plain Warp kernels only.

A test marked `@pytest.mark.usefixtures("warp_device")` (or taking `warp_device` as an argument)
runs once per device Warp sees: "cpu" everywhere, and "cuda:0", ... where there is a GPU. Its body
runs inside kernels._arrays.default_device_scope(device), so NumPy inputs go to that device and
objects made without a `device` live there; results still come back as NumPy arrays. CI has no GPU,
so there these tests run on the CPU only; .ci/cuda_check runs them on a GPU machine.
`DRLAB_TEST_DEVICES` (comma-separated, e.g. "cuda:0") narrows the list.

Ctrl-C: the interruption tests send SIGINT to pytest itself and to the runs they start. A shell
that starts the suite as a background job (`make test &`, `nohup ... &` in a script) starts it
with SIGINT ignored, which Python then keeps and every child inherits; pytest_configure puts
Python's own handler back, so each test sees what a terminal's Ctrl-C does.
"""

from __future__ import annotations

import os
import signal

import pytest


def warp_devices() -> list[str]:
    from research.warp_runtime import init_warp

    init_warp()
    import warp as wp

    seen = [str(d) for d in wp.get_devices()]
    wanted = [d.strip() for d in os.environ.get("DRLAB_TEST_DEVICES", "").split(",") if d.strip()]
    missing = [d for d in wanted if d not in seen]
    if missing:
        raise pytest.UsageError(f"DRLAB_TEST_DEVICES: {missing} not among the devices Warp sees ({seen})")
    return wanted or seen


def pytest_configure(config):
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # see the module docstring
        signal.signal(signal.SIGINT, signal.default_int_handler)
    config.addinivalue_line("markers", "cpu_fast_path: tests a CPU fast path itself; skipped while the fast paths "
                                       "are off (DRLAB_FAST_PATHS=0)")


def pytest_collection_modifyitems(config, items):
    from kernels import fast_paths

    if fast_paths.enabled():
        return
    skip = pytest.mark.skip(reason="tests a CPU fast path, and the fast paths are off (kernels.fast_paths)")
    for item in items:
        if item.get_closest_marker("cpu_fast_path") is not None:
            item.add_marker(skip)


def pytest_generate_tests(metafunc):
    if "warp_device" in metafunc.fixturenames:
        metafunc.parametrize("warp_device", warp_devices(), indirect=True)


@pytest.fixture
def warp_device(request):
    from kernels._arrays import default_device_scope

    with default_device_scope(request.param) as dev:
        yield dev
