"""Warp functions shared by the field kernels: output activations and their derivatives.

    softplus(x) = log(1 + e^x),           softplus'(x) = sigmoid(x)
    sigmoid(x)  = 1 / (1 + e^-x),         sigmoid'(x)  = sigmoid(x) (1 - sigmoid(x))   (sigmoid_vjp: from the output)
    exp_act(x)  = exp(min(x, EXP_CLAMP)), derivative exp(x) below the clamp, 0 above it

Density activation codes: DENSITY_SOFTPLUS (DVGO, Sun et al. 2022) and DENSITY_EXP (instant-ngp's
exponential, truncated so that a large raw output cannot overflow float32).
"""

from __future__ import annotations

import typing

import warp as wp

wp.set_module_options({"enable_backward": False})

DENSITY_SOFTPLUS = 0
DENSITY_EXP = 1
DENSITY_ACTIVATIONS = {"softplus": DENSITY_SOFTPLUS, "exp": DENSITY_EXP}
EXP_CLAMP = 15.0


@wp.func
def sigmoid(x: typing.Any):
    one = type(x)(1.0)
    if x >= type(x)(0.0):
        return one / (one + wp.exp(-x))
    e = wp.exp(x)
    return e / (one + e)


@wp.func
def sigmoid_vjp(g: typing.Any, s: typing.Any):
    """g sigmoid'(x) written with the output s = sigmoid(x): g s (1 - s)."""
    return g * s * (type(s)(1.0) - s)


@wp.func
def softplus(x: typing.Any):
    return wp.max(x, type(x)(0.0)) + wp.log(type(x)(1.0) + wp.exp(-wp.abs(x)))


@wp.func
def density_act(x: typing.Any, kind: int):
    if kind == 1:
        return wp.exp(wp.min(x, type(x)(15.0)))
    return softplus(x)


@wp.func
def density_act_grad(x: typing.Any, kind: int):
    if kind == 1:
        if x > type(x)(15.0):
            return type(x)(0.0)
        return wp.exp(x)
    return sigmoid(x)


def density_code(name: str, activation: str) -> int:
    """The kernel code of a density activation name ("softplus" or "exp"); ValueError naming `name`."""
    if activation not in DENSITY_ACTIVATIONS:
        raise ValueError(f"{name}: expected one of {sorted(DENSITY_ACTIVATIONS)}, got {activation!r}")
    return DENSITY_ACTIVATIONS[activation]
