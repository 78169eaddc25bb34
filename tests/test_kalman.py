"""Known-answer tests of the one constant-velocity Kalman filter (Yu & Medioni eqs. 6-8)."""

from __future__ import annotations

import numpy as np
import pytest

from aerotrack.kalman import (
    ConstantVelocityKF,
    cholesky_solve,
    filter_sequence,
    initiate,
    mahalanobis,
    measurement_noise,
    predict,
    process_noise,
    transition,
    update,
)


def test_transition_moves_position_by_velocity():
    x = np.array([10.0, 20.0, 4.0, 2.0, 3.0, -1.0])
    xp, _ = predict(x, np.eye(6), transition(2.0), np.zeros((6, 6)))
    np.testing.assert_allclose(xp, [16.0, 18.0, 4.0, 2.0, 3.0, -1.0])


def test_process_noise_is_white_acceleration():
    dt, a = 0.5, 2.0
    Q = process_noise(dt, a, 0.0)
    np.testing.assert_allclose(Q[0, 0], dt**4 / 4 * a**2)
    np.testing.assert_allclose(Q[0, 4], dt**3 / 2 * a**2)
    np.testing.assert_allclose(Q[4, 4], dt**2 * a**2)
    assert Q[0, 1] == 0 and Q[2, 2] == 0
    assert np.all(np.linalg.eigvalsh(Q) >= -1e-12)


def test_predict_covariance_matches_matrix_formula():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(6, 6))
    P = M @ M.T + np.eye(6)
    A, Q = transition(0.3), process_noise(0.3, 1.5, 0.2)
    _, Pp = predict(np.zeros(6), P, A, Q)
    np.testing.assert_allclose(Pp, A @ P @ A.T + Q, rtol=1e-12)


def test_update_matches_textbook_equations():
    rng = np.random.default_rng(2)
    M = rng.normal(size=(6, 6))
    P = M @ M.T + np.eye(6)
    x = rng.normal(size=6)
    z = rng.normal(size=4)
    R = np.diag([0.5, 0.4, 0.3, 0.2])
    H = np.eye(4, 6)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    e = z - H @ x
    xn, Pn, ll, d2 = update(x, P, z, R)
    np.testing.assert_allclose(xn, x + K @ e, rtol=1e-10)
    np.testing.assert_allclose(Pn, (np.eye(6) - K @ H) @ P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(d2, e @ np.linalg.solve(S, e), rtol=1e-10)
    expect = -0.5 * d2 - 0.5 * np.log(np.linalg.det(S)) - 2 * np.log(2 * np.pi)
    np.testing.assert_allclose(ll, expect, rtol=1e-10)


def test_cholesky_solve_and_logdet():
    S = np.array([[4.0, 1.0], [1.0, 3.0]])
    B = np.array([[1.0, 0.0], [0.0, 1.0]])
    X, logdet = cholesky_solve(S, B)
    np.testing.assert_allclose(X, np.linalg.inv(S), rtol=1e-12)
    np.testing.assert_allclose(logdet, np.log(11.0))
    X, logdet = cholesky_solve(np.array([[1.0, 2.0], [2.0, 1.0]]), B)
    assert np.isinf(logdet) and np.isnan(X).all()


def test_mahalanobis_and_logdet():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    S = A @ A.T + 0.5 * np.eye(4)
    e = rng.normal(size=4)
    d2, logdet = mahalanobis(S, e)
    np.testing.assert_allclose(d2, e @ np.linalg.solve(S, e), rtol=1e-10)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(S)[1], rtol=1e-10)
    d2, logdet = mahalanobis(np.array([[1.0, 2.0], [2.0, 1.0]]), np.ones(2))
    assert np.isinf(d2) and np.isinf(logdet)


def test_measurement_noise_grows_with_size():
    small = measurement_noise(np.array([1.0, 1.0]), 0.2, 0.1, 0.2, 0.1)
    big = measurement_noise(np.array([10.0, 10.0]), 0.2, 0.1, 0.2, 0.1)
    np.testing.assert_allclose(small[0, 0], 0.04 + 0.01)
    assert big[0, 0] > small[0, 0] and big[3, 3] > small[3, 3]


def test_initiate_puts_velocity_prior():
    x, P = initiate(np.array([1.0, 2.0, 3.0, 4.0]), np.eye(4) * 0.1, 5.0)
    np.testing.assert_allclose(x, [1, 2, 3, 4, 0, 0])
    assert P[4, 4] == pytest.approx(25.0)


def test_filter_recovers_constant_velocity():
    """Noise-free constant-velocity observations: the velocity converges to the truth and the
    innovations vanish."""
    kf = ConstantVelocityKF(accel_std=0.5, pos_std=0.1, pos_frac=0.0)
    t = np.arange(40) / 10.0
    zs = np.column_stack([3.0 + 2.0 * t, -1.0 - 1.5 * t, np.full(40, 4.0), np.full(40, 2.0)])
    xs, Ps, ll = kf.filter(zs, t)
    np.testing.assert_allclose(xs[-1, 4:], [2.0, -1.5], atol=1e-3)
    np.testing.assert_allclose(xs[-1, :4], zs[-1], atol=1e-3)
    assert ll[0] == 0.0 and np.all(np.isfinite(ll))
    # variance shrinks as evidence accumulates
    assert Ps[-1, 4, 4] < Ps[1, 4, 4]


def test_gap_is_one_step_with_larger_uncertainty():
    kf = ConstantVelocityKF()
    x, P = kf.initiate([0, 0, 4, 2])
    _, P1 = kf.predict(x, P, 0.1)
    _, P5 = kf.predict(x, P, 0.5)
    assert P5[0, 0] > P1[0, 0]
    # the compiled sequence filter agrees with the step-by-step methods
    zs = np.array([[0, 0, 4, 2], [1, 0.5, 4, 2], [3.1, 1.4, 4.1, 2]], float)
    t = np.array([0.0, 0.1, 0.3])
    xs, _, _, d2 = filter_sequence(zs, t, kf.as_array())
    x, P = kf.initiate(zs[0])
    for i in (1, 2):
        x, P = kf.predict(x, P, t[i] - t[i - 1])
        x, P, _, d = kf.update(x, P, zs[i])
        assert d == pytest.approx(d2[i])
    np.testing.assert_allclose(x, xs[-1])
