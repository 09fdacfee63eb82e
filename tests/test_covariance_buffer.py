"""``local_model(..., buffers=CovarianceBuffer())``: the covariance written into a reused
buffer (``window="auto"``'s fits share one) is the fresh fit's, bit for bit."""

import numpy as np

from lcmr_xr.kernels.local_models import CovarianceBuffer, local_model


def _data(m=96, seed=0):
    rng = np.random.default_rng(seed)
    R = np.fft.fft(rng.standard_normal((m, 2)), axis=0)
    G = np.array([[1.0 + 0.5j, -0.3j], [0.2, 2.0 - 1.0j], [0.7j, 0.1]])
    Z = R @ G.T + 0.05 * np.fft.fft(rng.standard_normal((m, 3)), axis=0)
    return R, Z


def test_fits_in_one_buffer_equal_fresh_fits():
    R, Z = _data()
    buf = CovarianceBuffer()
    for n, bins in ((4, (0, 48)), (7, (0, 56)), (5, (8, 40))):
        want = local_model(R, Z, half_width=n, degrees=(1, 1, 1), bins=bins)
        got = local_model(R, Z, half_width=n, degrees=(1, 1, 1), bins=bins, buffers=buf)
        for name in ("G", "T", "G_cov", "noise_variance", "condition"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    # the buffer is reused: the last fit's covariance is a view of it, the first's
    # (larger) allocation holds it
    first = buf.take((56, 6, 6), complex)
    assert np.shares_memory(first, got.G_cov)


def test_selected_bins_in_a_buffer_equal_the_fit_of_every_bin():
    R, Z = _data(seed=1)
    buf = CovarianceBuffer()
    local_model(R, Z, half_width=9, degrees=(1, 1, 1), bins=(0, 64), buffers=buf)  # other values
    select = np.arange(R.shape[0]) % 3 == 0
    got = local_model(R, Z, half_width=6, degrees=(1, 1, 1), bins=(0, 64), select=select,
                      buffers=buf)
    want = local_model(R, Z, half_width=6, degrees=(1, 1, 1), bins=(0, 64))
    on = select[:64]
    np.testing.assert_array_equal(got.G_cov[on], want.G_cov[on])
    np.testing.assert_array_equal(got.G[on], want.G[on])
    assert np.isnan(got.G[~on]).all() and got.ill_posed[~on].all()  # as without buffers


def test_bins_not_fitted_without_select_are_nan_in_a_buffer():
    # circular=False: the bins within a half-width of either end are not fitted; their
    # covariance is NaN as in fresh memory, not the values an earlier fit left in the buffer
    R, Z = _data(seed=2)
    buf = CovarianceBuffer()
    local_model(R, Z, half_width=9, degrees=(1, 1, 1), buffers=buf)  # fills every row
    got = local_model(R, Z, half_width=6, degrees=(1, 1, 1), circular=False, buffers=buf)
    want = local_model(R, Z, half_width=6, degrees=(1, 1, 1), circular=False)
    assert np.isnan(want.G_cov[:6]).all() and np.isnan(want.G_cov[-6:]).all()
    np.testing.assert_array_equal(got.G_cov, want.G_cov)
