"""Discriminative Kalman filter: the plain-Kalman limit against an independent Kalman filter, the DKF update in
closed form, noise reduction, tracking a commanded motion without lag, and angle wrap-around."""

import math

import numpy as np
import pytest

from simshear_gym.models.bayes_filter import (
    BayesFilterConfig,
    DiscriminativeKalmanFilter,
)
from simshear_gym.models.gdnn import variable_set


def kalman_step(mean, cov, u, z, A, B, G, R):
    """Textbook Kalman filter, gain form with H = I (written independently of the module's information form)."""
    mean = A @ mean + B @ u
    cov = A @ cov @ A.T + G
    gain = cov @ np.linalg.inv(cov + R)
    mean = mean + gain @ (z - mean)
    cov = (np.eye(len(mean)) - gain) @ cov
    return mean, cov


def test_scalar_plain_kalman_matches_closed_form():
    rng = np.random.default_rng(0)
    config = BayesFilterConfig(process_std=(0.3,))
    dkf = DiscriminativeKalmanFilter(config)
    mean, cov = np.array([1.0]), np.array([[4.0]])
    dkf.reset(mean, cov)
    one = np.eye(1)
    for _ in range(25):
        u, z, r = rng.normal(size=1), rng.normal(size=1) * 3, rng.uniform(0.2, 2.0)
        mean, cov = kalman_step(mean, cov, u, z, one, one, one * 0.09, one * r ** 2)
        dkf.predict(u)
        dkf.update(z, [r])
        assert not dkf.used_fallback
        np.testing.assert_allclose(dkf.mean, mean, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(dkf.cov, cov, rtol=1e-10)


@pytest.mark.parametrize("full_measurement_cov", [False, True])
def test_2d_plain_kalman_matches_closed_form(full_measurement_cov):
    rng = np.random.default_rng(1)
    A = np.array([[0.99, 0.05], [-0.02, 0.97]])
    B = np.array([[1.0], [0.5]])
    config = BayesFilterConfig(process_std=(0.2, 0.1), transition=tuple(map(tuple, A)), control=tuple(map(tuple, B)))
    G = np.diag([0.04, 0.01])
    dkf = DiscriminativeKalmanFilter(config)
    mean, cov = np.array([0.5, -1.0]), np.array([[2.0, 0.3], [0.3, 1.0]])
    dkf.reset(mean, cov)
    for _ in range(25):
        u, z = rng.normal(size=1), rng.normal(size=2)
        root = rng.normal(size=(2, 2))
        R = root @ root.T + 0.1 * np.eye(2) if full_measurement_cov else np.diag(rng.uniform(0.1, 1.0, 2))
        mean, cov = kalman_step(mean, cov, u, z, A, B, G, R)
        dkf.predict(u)
        if full_measurement_cov:
            dkf.update(z, measurement_cov=R)
        else:
            dkf.update(z, np.sqrt(np.diag(R)))
        np.testing.assert_allclose(dkf.mean, mean, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(dkf.cov, cov, rtol=1e-9, atol=1e-12)


def test_dkf_update_closed_form_and_infinite_prior_limit():
    m_prior, s_prior = 2.0, 1.5
    config = BayesFilterConfig(process_std=(0.5,), prior_std=(s_prior,), prior_mean=(m_prior,))
    dkf = DiscriminativeKalmanFilter(config)
    dkf.reset([1.0], [[0.8]])
    dkf.predict([0.3])
    dkf.update([1.6], [0.7])
    m_pred, M = 1.3, 0.8 + 0.25
    S = 1.0 / (1.0 / M + 1.0 / 0.49 - 1.0 / s_prior ** 2)
    m = S * (m_pred / M + 1.6 / 0.49 - m_prior / s_prior ** 2)
    assert not dkf.used_fallback
    assert dkf.cov[0, 0] == pytest.approx(S, rel=1e-12) and dkf.mean[0] == pytest.approx(m, rel=1e-12)

    def run(prior_std):
        rng = np.random.default_rng(2)
        dkf = DiscriminativeKalmanFilter(BayesFilterConfig(process_std=(0.2, 0.3), prior_std=prior_std,
                                                           prior_mean=(5.0, -5.0)))
        dkf.reset([0.0, 0.0], np.eye(2))
        for _ in range(10):
            dkf.step(rng.normal(size=2), rng.normal(size=2), rng.uniform(0.3, 1.0, 2))
        return dkf.mean, dkf.cov

    plain_mean, plain_cov = run(None)
    huge_mean, huge_cov = run((1e7, 1e7))
    np.testing.assert_allclose(huge_mean, plain_mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(huge_cov, plain_cov, rtol=1e-9)
    finite_mean, _ = run((2.0, 2.0))
    assert np.abs(finite_mean - plain_mean).max() > 1e-3  # a finite prior does change the estimate


def test_dkf_recovers_kalman_when_network_is_exact_posterior():
    """If the network returns the exact posterior under the prior N(m0, S0) of a reading x ~ N(z, R), dividing out
    the prior makes the DKF the Kalman filter on (x, R)."""
    rng = np.random.default_rng(3)
    m0, s0 = np.array([1.0, -2.0]), np.array([3.0, 2.0])
    S0_inv = np.diag(1.0 / s0 ** 2)
    config = BayesFilterConfig(process_std=(0.1, 0.2), prior_std=tuple(s0), prior_mean=tuple(m0))
    dkf = DiscriminativeKalmanFilter(config)
    mean, cov = np.zeros(2), np.eye(2)
    dkf.reset(mean, cov)
    G = np.diag([0.01, 0.04])
    for _ in range(15):
        u, x = rng.normal(size=2) * 0.2, m0 + rng.normal(size=2)
        root = rng.normal(size=(2, 2)) * 0.5
        R = root @ root.T + 0.05 * np.eye(2)
        R_inv = np.linalg.inv(R)
        Q = np.linalg.inv(S0_inv + R_inv)
        f = Q @ (S0_inv @ m0 + R_inv @ x)
        mean, cov = kalman_step(mean, cov, u, x, np.eye(2), np.eye(2), G, R)
        dkf.predict(u)
        dkf.update(f, measurement_cov=Q)
        assert not dkf.used_fallback
        np.testing.assert_allclose(dkf.mean, mean, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(dkf.cov, cov, rtol=1e-8, atol=1e-10)


def test_fallback_to_plain_kalman_when_network_is_less_sure_than_prior():
    def updated(prior_std):
        dkf = DiscriminativeKalmanFilter(BayesFilterConfig(process_std=(0.1,), prior_std=prior_std))
        dkf.reset([0.0], [[1.0]])
        dkf.update([2.0], [3.0])  # network std 3 > prior std 2
        return dkf

    fallback, plain = updated((2.0,)), updated(None)
    assert fallback.used_fallback and not plain.used_fallback
    np.testing.assert_allclose(fallback.mean, plain.mean)
    np.testing.assert_allclose(fallback.cov, plain.cov)
    assert fallback.cov[0, 0] < 1.0  # the update never adds uncertainty


def test_constant_state_noise_is_reduced():
    rng = np.random.default_rng(4)
    truth, noise_std = np.array([3.0, -1.0]), np.array([0.5, 0.3])
    dkf = DiscriminativeKalmanFilter(BayesFilterConfig(process_std=(0.01, 0.01)))
    first = truth + rng.normal(size=2) * noise_std
    dkf.reset(first, np.diag(noise_std ** 2))
    raw_errors, filtered_errors = [], []
    for _ in range(200):
        z = truth + rng.normal(size=2) * noise_std
        dkf.step(None, z, noise_std)
        raw_errors.append(z - truth)
        filtered_errors.append(dkf.mean - truth)
    raw_rms = np.sqrt(np.mean(np.square(raw_errors[20:]), axis=0))
    filtered_rms = np.sqrt(np.mean(np.square(filtered_errors[20:]), axis=0))
    assert np.all(filtered_rms < 0.4 * raw_rms), (filtered_rms, raw_rms)


def track(commanded: bool, steps=300, step_mm=0.2, noise_std=0.5, seed=5):
    rng = np.random.default_rng(seed)
    dkf = DiscriminativeKalmanFilter(BayesFilterConfig(process_std=(0.05,)))
    truth = np.array([0.0])
    dkf.reset(truth + rng.normal(size=1) * noise_std, [[noise_std ** 2]])
    raw, filtered = [], []
    for t in range(steps):
        u = np.array([step_mm * (1.0 if (t // 100) % 2 == 0 else -0.5)])  # ramps with a change of direction
        truth = truth + u + rng.normal(size=1) * 0.02
        z = truth + rng.normal(size=1) * noise_std
        dkf.step(u if commanded else None, z, [noise_std])
        raw.append((z - truth)[0])
        filtered.append((dkf.mean - truth)[0])
    return np.array(raw[10:]), np.array(filtered[10:])


def test_moving_state_with_commanded_motion_is_tracked_without_lag():
    step_mm = 0.2
    raw, filtered = track(commanded=True, step_mm=step_mm)
    assert np.mean(np.abs(filtered)) < 0.6 * np.mean(np.abs(raw))
    assert abs(np.mean(filtered[:80])) < 0.25 * step_mm  # no lag while moving in one direction
    _, blind = track(commanded=False, step_mm=step_mm)
    assert np.mean(filtered[:80]) - np.mean(blind[:80]) > step_mm  # without the motion model the estimate lags


def test_angle_wrap():
    config = BayesFilterConfig(process_std=(1.0,), periodic=(True,))
    dkf = DiscriminativeKalmanFilter(config)
    dkf.reset([175.0], [[100.0]])
    dkf.update([-175.0], [10.0])  # equal weights: the midpoint is 180, not 0
    assert abs((dkf.mean[0] - 180.0 + 180.0) % 360.0 - 180.0) < 1e-9
    assert -180.0 <= dkf.mean[0] < 180.0
    dkf.reset([179.0], [[1.0]])
    dkf.predict([3.0])
    assert dkf.mean[0] == pytest.approx(-178.0)
    dkf.update([-177.0], [1.0])
    assert dkf.mean[0] == pytest.approx(-178.0 + 2.0 / 3.0)  # K = 2 / (2 + 1) on an innovation of +1 deg


def test_config_from_edge_variables():
    edge = variable_set("edge")
    config = BayesFilterConfig.from_output_specs(edge.variables, process_std=(0.1,) * edge.dim)
    assert config.periodic == edge.periodic and config.names == edge.names
    assert math.isinf(config.prior_std[2]) and config.prior_std[0] == pytest.approx(12.0 / math.sqrt(12.0))
    assert config.prior_mean[1] == pytest.approx(4.0)
    dkf = DiscriminativeKalmanFilter(config)
    start = np.array([0.0, 4.0, 178.0, 0.0, 0.0, 0.0])
    dkf.reset(start, np.diag([1.0, 0.25, 25.0, 1.0, 1.0, 1.0]))
    dkf.step(np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.0]), np.array([0.1, 4.1, -178.0, 0.2, 0.1, 0.0]), np.ones(6))
    assert abs(dkf.mean[2] + 178.0) < 1.0 and np.all(np.isfinite(dkf.cov))


def test_errors():
    dkf = DiscriminativeKalmanFilter(BayesFilterConfig(process_std=(0.1, 0.1)))
    with pytest.raises(RuntimeError, match="reset"):
        dkf.predict()
    with pytest.raises(ValueError, match="np.diag"):
        dkf.reset([0.0, 0.0], [1.0, 1.0])
    dkf.reset([0.0, 0.0], np.eye(2))
    with pytest.raises(ValueError, match="exactly one"):
        dkf.update([0.0, 0.0])
    with pytest.raises(ValueError, match="commanded_delta"):
        dkf.predict([1.0])
    with pytest.raises(ValueError, match="prior_std must have 2"):
        BayesFilterConfig(process_std=(0.1, 0.1), prior_std=(1.0,))
    with pytest.raises(ValueError, match="1 to 6"):
        BayesFilterConfig(process_std=(0.1,) * 7)
