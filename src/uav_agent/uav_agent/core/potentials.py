"""The smooth building blocks of the flocking law: sigma-norm, bump, phi and Phi (eq. 1, 7, 8, 11)."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def sigma_norm(z: ArrayLike, epsilon: float) -> F64:
    """||z||_sigma of eq. 7 for vectors along the last axis.

    Differentiable at 0, unlike ||z||, which keeps the potentials smooth.
    """
    z = np.asarray(z, dtype=float)
    return (np.sqrt(1.0 + epsilon * np.sum(z * z, axis=-1)) - 1.0) / epsilon


def sigma_abs(x: ArrayLike, epsilon: float) -> F64:
    """||x||_sigma of eq. 7 for scalars, elementwise (user counts in eq. 10, distances d and r in eq. 11)."""
    x = np.asarray(x, dtype=float)
    return (np.sqrt(1.0 + epsilon * x * x) - 1.0) / epsilon


def sigma_grad(z: ArrayLike, epsilon: float) -> F64:
    """Gradient of the sigma-norm, eq. 8: z / sqrt(1 + eps ||z||^2); v_ij of eq. 10 with z = q_j - q_i."""
    z = np.asarray(z, dtype=float)
    return z / np.sqrt(1.0 + epsilon * np.sum(z * z, axis=-1, keepdims=True))


def bump(z: ArrayLike, z1: float, z0: float) -> F64:
    """alpha_{z1,z0}(z) of eq. 1: 1 below z1, a half cosine down to 0 at z0, 0 beyond."""
    z = np.asarray(z, dtype=float)
    span = z0 - z1
    mid = 0.5 * (1.0 + np.cos(np.pi * (z - z1) / span))
    return np.where(z < z1, 1.0, np.where(z < z0, mid, 0.0))


def phi(z: ArrayLike, a: float, b: float) -> F64:
    """Uneven sigmoid of eq. 11; phi(0) = 0 holds for 0 < a <= b, the scenario check enforces it."""
    c = abs(a - b) / np.sqrt(4.0 * a * b)
    s = np.asarray(z, dtype=float) + c
    return 0.5 * ((a + b) * s / np.sqrt(1.0 + s * s) + (a - b))


def action(z_sigma: ArrayLike, d: float, r: float, epsilon: float, a: float, b: float, gamma: float) -> F64:
    """Phi of eq. 11 at a pair's sigma-distance: zero at d, repulsive inside, attractive out to r, 0 beyond."""
    r_sigma = sigma_abs(r, epsilon)
    d_sigma = sigma_abs(d, epsilon)
    z = np.asarray(z_sigma, dtype=float)
    return bump(z / r_sigma, gamma, 1.0) * phi(z - d_sigma, a, b)
