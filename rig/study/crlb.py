"""The Cramér-Rao bound on the variance of an unbiased estimate of k, for a design and a scatter model.

The model of a slip mass at distance l_i (the one the simulated world draws from):

    m_i ~ Normal(mu_i, v_i),  mu_i = k / l_i,  v_i = A + B * mu_i^2,

with A = a^2 (additive scatter, kg^2) and B = b^2 (multiplicative scatter: b is the relative sd of
the joint's capacity from trial to trial). Pure additive scatter is B = 0, pure multiplicative
A = 0, mixed both > 0.

For independent normal observations whose mean and variance depend on parameters theta, the
Fisher information is

    I_jk = sum_i [ dmu_i/dtheta_j * dmu_i/dtheta_k / v_i + dv_i/dtheta_j * dv_i/dtheta_k / (2 v_i^2) ].

Here theta = (k, A, B), with

    dmu_i/dk = 1 / l_i,  dv_i/dk = 2 B k / l_i^2,  dv_i/dA = 1,  dv_i/dB = k^2 / l_i^2.

The scatter's size is not known to the experimenter, so A and B are nuisance parameters estimated
with k: the bound on var(k_hat) is the (k, k) element of the inverse of I over k and the nuisance
parameters the true scatter has (A for additive, B for multiplicative, both for mixed). A nuisance
parameter the truth lacks is left out: it is zero, on the boundary, and an estimator that knows the
shape loses nothing to it.

Check, pure multiplicative (A = 0): I_kk = n (1/B + 2) / k^2, I_kB = n / (B k), I_BB = n / (2 B^2);
the efficient information is I_kk - I_kB^2 / I_BB = n / (B k^2), so the bound is b^2 k^2 / n: exactly
the variance of the mean of m_i l_i (each trial one draw of k times a capacity factor). Pure
additive (B = 0): the bound is a^2 / sum(1 / l_i^2), the variance of the weighted least-squares
slope, which the paper's fit through the origin attains.

The world clips its capacity factor at +-3 sd and at a floor; both change the bound by far less
than a study can resolve and are ignored. Censored trials (no slip before the force limit) are
counted as full observations, so the bound is, if anything, too low (the ratio MSE / bound too
high), never flattering.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def crlb_k_variance(
    distances_m: Sequence[float], k_kg_m: float, scatter_a_kg: float, scatter_b: float
) -> float:
    """The Cramér-Rao bound on var(k_hat) [kg^2 m^2] for slip masses at `distances_m` (see module docstring).

    `scatter_a_kg` and `scatter_b` are the true additive sd [kg] and relative sd of one slip mass.
    NaN when the design carries no information (no distances, or no scatter at all).
    """
    distances = np.asarray(distances_m, dtype=float)
    if distances.size == 0 or not (scatter_a_kg > 0 or scatter_b > 0):
        return math.nan
    if not (np.all(np.isfinite(distances)) and np.all(distances > 0)):
        raise ValueError("distances must be finite and > 0")
    big_a, big_b = scatter_a_kg**2, scatter_b**2
    inv_l = 1.0 / distances
    mu = k_kg_m * inv_l
    v = big_a + big_b * mu**2
    dmu = [inv_l]  # d mu / d theta for theta = (k, nuisance...)
    dv = [2.0 * big_b * k_kg_m * inv_l**2]
    if big_a > 0:
        dmu.append(np.zeros_like(inv_l))
        dv.append(np.ones_like(inv_l))
    if big_b > 0:
        dmu.append(np.zeros_like(inv_l))
        dv.append(k_kg_m**2 * inv_l**2)
    size = len(dmu)
    info = np.empty((size, size))
    for j in range(size):
        for m in range(size):
            info[j, m] = float(np.sum(dmu[j] * dmu[m] / v + dv[j] * dv[m] / (2.0 * v**2)))
    try:
        return float(np.linalg.inv(info)[0, 0])
    except np.linalg.LinAlgError:
        return math.nan  # e.g. mixed scatter at a single distance: A and B cannot be told apart
