"""Blocks of slow bins with a known noise covariance (``identify_spectra(noise_covariance=)``):
the covariance of every bin is built from that bin's window of the known covariance, also
where the spectra are mirrored (real signals) but the known covariance is not."""

import numpy as np
import pytest

from lcmr_xr import hdd
from lcmr_xr.kernels import identification as ki
from lcmr_xr.kernels.local_models import local_model
from lcmr_xr.kernels.pooling import rescale_covariance, window_mean

WINDOW = 20


@pytest.mark.parametrize("nbytes", [1, 1 << 60], ids=["16-bin-blocks", "one-block"])
def test_known_noise_covariance_not_mirrored(monkeypatch, nbytes):
    exp = hdd.simulate(n_samples=600, seed=3)
    factor = int(exp.attrs["factor"])
    R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=factor)
    shape = dict(n_fast=exp.sizes["time"], factor=factor, nu=exp.sizes["input"])
    m, nz = Z.shape[-2:]
    rng = np.random.default_rng(1)
    A = rng.standard_normal((m, nz, nz)) + 1j * rng.standard_normal((m, nz, nz))
    # Hermitian positive definite per bin; bin M - k unrelated to bin k
    scale = np.abs(Z)[:, :, None] * np.abs(Z)[:, None, :] * 1e-4
    noise = (A @ A.conj().swapaxes(-1, -2)) * scale
    k = np.arange(m)
    assert np.max(np.abs(noise[(-k) % m] - noise.conj())) > 0.1 * np.max(np.abs(noise))
    monkeypatch.setattr(ki, "BLOCK_BYTES", nbytes)
    got = ki.identify_spectra(R, Z, half_width=WINDOW, noise_covariance=noise, **shape)
    # the whole-circle pipeline: one local model, its G_cov rescaled bin by bin
    fit = local_model(R, Z, half_width=WINDOW)
    G_cov = rescale_covariance(fit.G_cov, fit.noise_covariance,
                               window_mean(noise, WINDOW, axis=-3, circular=True))
    want = ki.recover_frf(fit.G, G_cov, ny=nz - R.shape[-1], ill_posed=fit.ill_posed,
                          dof=fit.dof, **shape)
    want["G_var"] = np.real(np.diagonal(G_cov, axis1=-2, axis2=-1)).reshape(fit.G.shape)
    for name in ("P", "P_var", "P_var_linear", "s_weak_rel_std", "G_var", "P_undetermined"):
        a, b = np.asarray(got[name]), np.asarray(want[name])
        if a.dtype.kind == "b":
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            fin = np.isfinite(b)
            np.testing.assert_array_equal(np.isfinite(a), fin, err_msg=name)
            # (bins M/2+1.. fitted directly here, mirrored by the whole fit: they agree to
            # the fits' rounding; a known covariance taken from bin k there is off by
            # percents)
            np.testing.assert_allclose(a[fin], b[fin], rtol=1e-5, atol=0, err_msg=name)
    assert np.isfinite(got["P_var"]).mean() > 0.9  # bands where determined: a real test
