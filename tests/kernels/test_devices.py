"""The device scope the device-parametrised tests and `drlab gradcheck --device` run in
(kernels._arrays.default_device_scope), and the CUDA check script's syntax."""

from __future__ import annotations

import pathlib
import subprocess

import numpy as np
import pytest
import warp as wp

from kernels import _arrays as A


def test_numpy_inputs_follow_the_scope(warp_device):
    # inside the fixture's scope: NumPy inputs, objects made without a device, and wp.array(x)
    x = np.zeros(3, np.float32)
    assert A.Inputs(None, x).device == warp_device
    assert A.get_device(None) == warp_device and A.default_device() == warp_device
    assert wp.array(x).device == warp_device
    # a wp.array's own device and an explicit device still win
    cpu = wp.get_device("cpu")
    assert A.Inputs(None, wp.array(x, device=cpu)).device == cpu
    assert A.Inputs("cpu", x).device == cpu


def test_scope_nests_and_restores():
    cpu = wp.get_device("cpu")
    assert A.default_device() == cpu
    with A.default_device_scope("cpu") as d1:
        assert d1 == cpu and A.default_device() == cpu
        with A.default_device_scope(cpu):
            assert A.default_device() == cpu
    assert A._DEFAULT_DEVICES == []
    with pytest.raises(ValueError, match="device: cannot use 'tpu'"):
        with A.default_device_scope("tpu"):
            pass
    assert A._DEFAULT_DEVICES == []


def test_cuda_check_script_parses():
    script = pathlib.Path(__file__).parents[2] / ".ci" / "cuda_check"
    assert script.stat().st_mode & 0o111, "not executable"
    subprocess.run(["bash", "-n", str(script)], check=True)
