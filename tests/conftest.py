"""Shared pytest set-up: the devices the device-parametrised tests run on.

A test marked `@pytest.mark.usefixtures("warp_device")` (or taking `warp_device` as an argument)
runs once per device Warp sees: "cpu" everywhere, and "cuda:0", ... where there is a GPU. Its body
runs inside kernels._arrays.default_device_scope(device), so NumPy inputs go to that device and
objects made without a `device` live there; results still come back as NumPy arrays. CI has no GPU,
so there these tests run on the CPU only; .ci/cuda_check runs them on a GPU machine.
`DRLAB_TEST_DEVICES` (comma-separated, e.g. "cuda:0") narrows the list.
"""

from __future__ import annotations

import os

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


def pytest_generate_tests(metafunc):
    if "warp_device" in metafunc.fixturenames:
        metafunc.parametrize("warp_device", warp_devices(), indirect=True)


@pytest.fixture
def warp_device(request):
    from kernels._arrays import default_device_scope

    with default_device_scope(request.param) as dev:
        yield dev
