"""The noise contract of the measurement models: covariance, its factor, whitening and draws agree."""

from __future__ import annotations

import numpy as np

from calib_oed.measurement.error_model import ErrorModel
from calib_oed.measurement.noise import TrackerNoise


def test_the_noise_contract_of_both_kinds():
    y = np.array([[3.0, 0.5, 0.2], [1.0, -2.0, 0.4]])
    noise = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6), 1.4e-5)
    full, iso = ErrorModel(noise=noise).model(0), ErrorModel(sigma=2e-5).model(0)
    assert np.allclose(full.noise_covariance(y), noise.covariance(y))
    for m in (full, iso):
        c, w, cov = m.noise_cholesky(y), m.noise_whitening(y), m.noise_covariance(y)
        assert np.allclose(c @ np.swapaxes(c, 1, 2), cov) and np.allclose(w @ c, np.eye(3))
    rows = np.array([[1e-5, 2e-5, 3e-5], [4e-5, 4e-5, 4e-5]])
    assert np.allclose(iso.noise_covariance(y, rows)[0], np.diag(rows[0] ** 2))
    draws = np.stack([full.sample_noise(y, np.random.default_rng(k)) for k in range(3000)])
    assert np.allclose(np.einsum("kni,knj->nij", draws, draws) / 3000, noise.covariance(y), rtol=0.15,
                       atol=2e-11)
