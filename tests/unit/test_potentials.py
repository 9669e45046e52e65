"""The smooth building blocks and the control terms against independent expectations."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import minimize

from uav_agent.core.control import (bridge_term, connectivity_potential, flocking_terms, goal_term,
                                    overload_weight, spare_weight)
from uav_agent.core.params import FlockParams
from uav_agent.core.potentials import action, bump, phi, sigma_abs, sigma_grad, sigma_norm

P = FlockParams()
finite = st.floats(-200, 200, allow_nan=False)
vec3 = arrays(np.float64, 3, elements=finite)


def test_phi_is_zero_at_zero_even_when_uneven() -> None:
    for a, b in ((5.0, 5.0), (2.0, 7.0), (0.5, 9.0)):  # c = |a-b|/sqrt(4ab) needs 0 < a <= b
        assert abs(float(phi(0.0, a, b))) < 1e-12
        assert float(phi(-1.0, a, b)) < 0 < float(phi(1.0, a, b))


def test_bump_is_one_then_zero_and_continuous_at_both_cutoffs() -> None:
    z1, z0, eps = 0.2, 1.0, 1e-9
    assert bump(z1 - eps, z1, z0) == 1.0
    assert abs(bump(z1 + eps, z1, z0) - 1.0) < 1e-6
    assert abs(bump(z0 - eps, z1, z0)) < 1e-6
    assert bump(z0, z1, z0) == 0.0 and bump(5.0, z1, z0) == 0.0


@given(st.floats(-1, 3), st.floats(-1, 3))
def test_bump_never_increases(x: float, y: float) -> None:
    lo, hi = min(x, y), max(x, y)
    assert bump(lo, 0.2, 1.0) >= bump(hi, 0.2, 1.0)


@settings(max_examples=200)
@given(vec3)
def test_sigma_gradient_matches_finite_differences(z: np.ndarray) -> None:
    h = 1e-6
    numeric = np.array([(sigma_norm(z + h * e, P.epsilon) - sigma_norm(z - h * e, P.epsilon)) / (2 * h)
                        for e in np.eye(3)])
    assert np.allclose(sigma_grad(z, P.epsilon), numeric, atol=1e-6)


def test_sigma_norm_of_scalars_matches_vectors() -> None:
    x = np.array([0.0, 3.0, -4.5, 80.0])
    assert np.allclose(sigma_abs(x, P.epsilon), sigma_norm(x[:, None], P.epsilon))


@given(st.floats(0, 100))
def test_action_sign_zero_at_d_and_beyond_r(dist: float) -> None:
    value = float(action(sigma_abs(dist, P.epsilon), P.d, P.r, P.epsilon, P.a, P.b, P.gamma))
    if dist >= P.r:
        assert value == 0.0
    elif dist < P.d - 1e-6:
        assert value < 0.0
    elif dist > P.d + 1e-6:
        assert value > 0.0
    assert abs(float(action(sigma_abs(P.d, P.epsilon), P.d, P.r, P.epsilon, P.a, P.b, P.gamma))) < 1e-12


def _pair_force(dist: float, nu_j: float = 0.0) -> np.ndarray:
    own_q = np.array([[0.0, 0.0, 20.0]])
    nbr_q = np.array([[dist, 0.0, 20.0]])
    z = np.zeros((1, 3))
    return flocking_terms(own_q, z, np.zeros(1), np.zeros(1, np.intp), nbr_q, z, np.array([nu_j]), P)[0]


def test_pair_repels_inside_d_attracts_beyond_and_rests_at_d() -> None:
    assert _pair_force(12.0)[0] < 0
    assert _pair_force(22.0)[0] > 0
    assert np.allclose(_pair_force(P.d), 0.0, atol=1e-12)


def test_overloaded_neighbour_attracts() -> None:
    assert _pair_force(P.d, nu_j=150.0)[0] > 0.5
    assert overload_weight(np.array([0.0, P.n_max]), P).tolist() == [0.0, 0.0]


def test_velocity_consensus_weight_full_when_idle_none_at_capacity() -> None:
    w = spare_weight(np.array([0.0, 40.0, P.n_max, 200.0]), P)
    assert w[0] == 1.0 and 0.0 < w[1] < 1.0 and w[2] == 0.0 and w[3] == 0.0


def test_goal_term_rests_at_goal_and_pulls_towards_it() -> None:
    goal = np.array([10.0, -5.0, 20.0])
    assert np.allclose(goal_term(goal, np.zeros(3), goal, P), 0.0)
    assert np.dot(goal_term(np.array([0.0, 0.0, 20.0]), np.zeros(3), goal, P), goal - [0, 0, 20]) > 0


@settings(max_examples=100)
@given(vec3, vec3, vec3)
def test_bridge_term_is_the_descent_of_the_connectivity_potential(q: np.ndarray, q1: np.ndarray,
                                                                  q2: np.ndarray) -> None:
    h = 1e-5
    grad = np.array([(connectivity_potential(q + h * e, q1, q2, P) - connectivity_potential(q - h * e, q1, q2, P))
                     / (2 * h) for e in np.eye(3)])
    assert np.allclose(bridge_term(q, np.zeros(3), q1, q2, P), -grad, atol=1e-4 * (1 + np.abs(grad).max()))


@settings(max_examples=60, deadline=None)
@given(vec3, vec3, vec3)
def test_connectivity_potential_is_lowest_on_the_segment(q: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> None:
    ab = q2 - q1
    t = np.clip(np.dot(q - q1, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0)
    foot = q1 + t * ab
    assert connectivity_potential(foot, q1, q2, P) <= connectivity_potential(q, q1, q2, P) + 1e-9
    best = minimize(lambda x: float(connectivity_potential(x, q1, q2, P)), q, method='BFGS').x
    seg_t = np.clip(np.dot(best - q1, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0)
    assert np.linalg.norm(best - (q1 + seg_t * ab)) < 1e-2 * (1 + np.linalg.norm(ab))
