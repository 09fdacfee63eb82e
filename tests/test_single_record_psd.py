"""One record's residual noise covariance, estimated entry by entry, is mended to a
covariance before it feeds the band (issue: a released bin with a zero-width band).

The local model estimates ``s_ij = c_ij / tau_ij`` one entry at a time; on the HDD loop
the lifted ``u`` and ``y`` share their disturbances, the estimated correlations exceed 1
at some bins, and the first-order variance of ``P`` came out negative there and was
clipped to exactly 0 (``P_std == 0`` on a bin not flagged).  One record's fit now
rebuilds ``G_cov`` from :func:`lcmr_xr.kernels.pooling.nearest_correlation`
(``kernels.identification._positive_semidefinite``) at the bins where ``cov(P_1)`` is not
positive semidefinite (``_mend_indefinite``; pooled fits at every bin); ``P`` itself is not
touched."""

import numpy as np
import pytest

import lcmr_xr
from lcmr_xr.kernels import identification as kid


@pytest.fixture(scope="module")
def seed2_case1():
    return lcmr_xr.hdd.simulate(seed=2, case=1)


def test_no_released_bin_has_a_zero_band(seed2_case1):
    """The lead's example: seed 2, case 1, window 12 had P_std = P_std_linear = 0 at
    7700 Hz, PZT, not flagged (P = -0.235-0.014j, truth 0.859-0.440j; neighbours' 0.83-1.7)."""
    res = lcmr_xr.identify(seed2_case1, window=12)
    released = ~res.P_undetermined.values[:, None, None] & np.isfinite(res.P.values)
    for name in ("P_std", "P_std_linear"):
        std = res[name].values
        assert np.all(std[released] > 0), (name, res.frequency.values[np.nonzero(
            (std <= 0) & released)[0]])
    at = res.sel(frequency=7700.0, input="pzt").isel(output=0)
    assert not bool(at.P_undetermined)
    assert float(at.P_std_linear) > 0.1  # (neighbours 0.83-1.7; the mended value ~0.9)


@pytest.mark.parametrize("denominator", ["ls", "iv"])
def test_one_record_covariance_is_positive_semidefinite(monkeypatch, seed2_case1, denominator):
    """One record, window 12: cov(P_1) from the entry-by-entry estimate has negative
    eigenvalues at some bins (checked); mended, it is positive semidefinite at every bin,
    G and P_1 are bit for bit those of the fit without the mend, the variances of G (the
    noise covariance's diagonal kept) equal to rounding, and every output at the bins
    that needed nothing bit for bit."""
    exp = seed2_case1
    R, Z = kid.experiment_spectra(exp.r.values, exp.u.values, exp.y.values,
                                  factor=int(exp.attrs["factor"]))
    fit = dict(half_width=12, degrees=(3, 3, 3), circular=True, covariance=True,
               known_covariance=None, experiment_axis=None, closed_loop="indirect",
               denominator=denominator, spread=False)

    def min_eig(terms):
        C = terms["P1_cov"]
        ok = np.all(np.isfinite(C), axis=(-2, -1))
        lam = np.linalg.eigvalsh(C[ok])
        return lam[:, 0] / lam[:, -1]

    mended = kid._fit_terms(R, Z, **fit)
    with monkeypatch.context() as m:
        m.setattr(kid, "nearest_correlation", lambda s: s)
        as_estimated = kid._fit_terms(R, Z, **fit)
    assert min_eig(mended).min() >= -1e-9, min_eig(mended).min()
    assert np.sum(min_eig(as_estimated) < -1e-6) >= 1
    for name in ("G", "T", "P1"):
        np.testing.assert_array_equal(mended[name], as_estimated[name], err_msg=name)
    # (the estimate's diagonal carries imaginary rounding of ~1e-7 of its real part at the
    # smallest entries, which the rescaling by s_new_ii / s_ii turns into real rounding)
    np.testing.assert_allclose(mended["G_var"], as_estimated["G_var"], rtol=1e-6)
    same = min_eig(as_estimated) >= 0  # (over the bins with a finite cov(P_1))
    assert 0.5 < same.mean() < 1  # most bins need nothing (measured 0.9+)
    for name in ("P1_cov", "rho", "rho_v", "s_condition"):
        a, b = np.asarray(mended[name]), np.asarray(as_estimated[name])
        ok = np.all(np.isfinite(as_estimated["P1_cov"]), axis=(-2, -1))
        np.testing.assert_array_equal(a[ok][same], b[ok][same], err_msg=name)
        assert name != "P1_cov" or not np.array_equal(a[ok][~same], b[ok][~same])



def test_positive_semidefinite_leaves_covariances_alone():
    """The mend on one record's shapes (M, nz nr, nz nr): a bin whose noise covariance is
    one already is returned bit for bit; a bin with a correlation above 1 gets
    G_cov = s_new_ij X_ij (the closed form of the 2 x 2 nearest correlation matrix: the
    correlation 1.25 becomes 1, the variances kept)."""
    rng = np.random.default_rng(1)
    nz, nr = 2, 3
    X = rng.standard_normal((2, nz * nr, 8)) + 1j * rng.standard_normal((2, nz * nr, 8))
    X = X @ np.conj(np.swapaxes(X, -1, -2))  # the data factor per bin, Hermitian
    s = np.array([[[1.0, 0.5], [0.5, 4.0]], [[1.0, 2.5j], [-2.5j, 4.0]]])  # corr 0.25, 1.25
    ratio = np.repeat(np.repeat(s, nr, axis=-2), nr, axis=-1)
    G_cov = X * ratio
    out = kid._positive_semidefinite(G_cov, s)
    np.testing.assert_array_equal(out[0], G_cov[0])
    want = np.array([[1.0, 2.0j], [-2.0j, 4.0]])
    np.testing.assert_allclose(out[1], X[1] * np.repeat(np.repeat(want, nr, 0), nr, 1),
                               rtol=1e-12)
    assert np.linalg.eigvalsh(s[1])[0] < 0 and np.linalg.eigvalsh(want)[0] >= -1e-12


def test_an_entry_estimated_exactly_zero_leaves_the_bin_as_it_is():
    """Noiseless data give noise covariances of rounding with entries exactly 0 (HDD,
    N = 36 000, window 30: 102 bins that needed the mend); ``G_cov`` has no factor to
    rescale there (``rescale_covariance``: NaN), so such a bin keeps its ``G_cov`` (it
    had made ``P_std`` NaN and flagged bins of a noiseless record)."""
    s = np.array([[1.0, 0.0, 0.9], [0.0, 1.0, 0.9], [0.9, 0.9, 1.0]]) + 0j
    assert np.linalg.eigvalsh(s)[0] < 0  # a bin the mend would change
    rng = np.random.default_rng(2)
    X = rng.standard_normal((6, 9)) + 1j * rng.standard_normal((6, 9))
    G_cov = np.stack([X @ np.conj(X.T)] * 2)
    noise = np.stack([s, s * 1.0])
    noise[1, 0, 1] = noise[1, 1, 0] = 1e-3  # a neighbour with no zero: mended
    out = kid._positive_semidefinite(G_cov, noise)
    assert np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[0], G_cov[0])
    assert not np.array_equal(out[1], G_cov[1])
