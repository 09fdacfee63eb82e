"""Identities of lcmr_xr.kernels.lifting against numpy.fft and time-domain simulation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from lcmr_xr.kernels import lifting as lk


leading = st.lists(st.integers(1, 3), min_size=0, max_size=2).map(tuple)


@settings(deadline=None, max_examples=40)
@given(lead=leading, m=st.integers(1, 7), factor=st.integers(1, 5), seed=st.integers(0, 2**31))
def test_lift_unlift_round_trip_and_element_rule(lead, m, factor, seed):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(lead + (m * factor,))
    lifted = lk.lift(x, factor)
    assert lifted.shape == lead + (m, factor)
    for l in range(m):
        for j in range(factor):
            np.testing.assert_array_equal(lifted[..., l, j], x[..., l * factor + j])
    np.testing.assert_array_equal(lk.unlift(lifted), x)


def test_lift_refuses_non_multiple_with_fix():
    with pytest.raises(ValueError, match=r"10 samples.*factor 3.*Trim the signal to 9"):
        lk.lift(np.zeros(10), 3)
    with pytest.raises(ValueError, match="positive integer"):
        lk.lift(np.zeros(10), 0)


@settings(deadline=None, max_examples=40)
@given(lead=leading, m=st.integers(1, 9), factor=st.integers(1, 5), seed=st.integers(0, 2**31))
def test_fast_spectrum_from_lifted_equals_fft(lead, m, factor, seed):
    rng = np.random.default_rng(seed)
    n = m * factor
    x = rng.standard_normal(lead + (n,)) + 1j * rng.standard_normal(lead + (n,))
    lifted_spectrum = np.fft.fft(lk.lift(x, factor), axis=-2)  # M-point DFT of each phase
    fast = lk.fast_spectrum_from_lifted(lifted_spectrum)
    np.testing.assert_allclose(fast, np.fft.fft(x, axis=-1), rtol=0, atol=1e-12 * n)
    # and back
    np.testing.assert_allclose(
        lk.lifted_spectrum_from_fast(np.fft.fft(x, axis=-1), factor), lifted_spectrum,
        rtol=0, atol=1e-12 * n,
    )


def _iir_bank(ny, nu, rng):
    """Random stable IIR filters (b, a) per (output, input), poles of radius <= 0.8."""
    bank = []
    for _ in range(ny):
        row = []
        for _ in range(nu):
            radius = rng.uniform(0.2, 0.8, size=2)
            angle = rng.uniform(0, np.pi, size=2)
            poles = np.concatenate([radius * np.exp(1j * angle), radius * np.exp(-1j * angle)])
            a = np.real(np.poly(poles))
            b = rng.standard_normal(4)
            row.append((b, a))
        bank.append(row)
    return bank


def _frf(bank, n):
    """Exact FRF of the bank on all n fast bins, (n, ny, nu)."""
    w = 2 * np.pi * np.arange(n) / n
    out = np.empty((n, len(bank), len(bank[0])), complex)
    for i, row in enumerate(bank):
        for j, (b, a) in enumerate(row):
            out[:, i, j] = scipy.signal.freqz(b, a, worN=w)[1]
    return out


def _simulate_steady_state(bank, u_period, periods=12):
    """Periodic steady state of y = P u over one period: run many periods, keep the last."""
    n, nu = u_period.shape
    u = np.tile(u_period, (periods, 1))
    y = np.zeros((u.shape[0], len(bank)))
    for i, row in enumerate(bank):
        for j, (b, a) in enumerate(row):
            y[:, i] += scipy.signal.lfilter(b, a, u[:, j])
    return y[-n:]


def _lifted_spectrum_phase_major(x, factor):
    """(N, c) -> (M, F c) with lifted channel j c + ch, DFT along the slow axis."""
    n, c = x.shape
    lifted = lk.lift(x.T, factor)  # (c, M, F)
    spec = np.fft.fft(lifted, axis=-2)  # (c, M, F)
    return np.transpose(spec, (1, 2, 0)).reshape(n // factor, factor * c)


@pytest.mark.parametrize("factor", [2, 3, 4])
@pytest.mark.parametrize("ny,nu", [(1, 1), (2, 2), (1, 2)])
def test_lifted_frf_matches_time_domain_simulation(factor, ny, nu):
    rng = np.random.default_rng(100 * factor + 10 * ny + nu)
    m = 10
    n = m * factor
    bank = _iir_bank(ny, nu, rng)
    u = rng.standard_normal((n, nu))
    y = _simulate_steady_state(bank, u, periods=60)  # 0.8**(60 n) is far below eps
    pbar = lk.lifted_frf(_frf(bank, n), factor)  # (M, F ny, F nu)
    ubar = _lifted_spectrum_phase_major(u, factor)
    ybar = _lifted_spectrum_phase_major(y, factor)
    predicted = np.einsum("mab,mb->ma", pbar, ubar)
    scale = np.max(np.abs(ybar))
    np.testing.assert_allclose(predicted, ybar, rtol=0, atol=1e-10 * scale)


@pytest.mark.parametrize("factor", [2, 3, 4])
@pytest.mark.parametrize("ny,nu", [(1, 1), (2, 3)])
def test_frf_from_first_block_row_recovers_frf(factor, ny, nu):
    rng = np.random.default_rng(factor + ny + nu)
    n = 8 * factor
    p = rng.standard_normal((2, n, ny, nu)) + 1j * rng.standard_normal((2, n, ny, nu))
    first_row = lk.lifted_frf(p, factor)[..., :ny, :]
    np.testing.assert_allclose(lk.frf_from_first_block_row(first_row, factor), p, atol=1e-12)


def test_first_block_row_weights_reproduce_recovery():
    rng = np.random.default_rng(5)
    factor, m = 3, 6
    n = factor * m
    p1 = rng.standard_normal((m, 1, factor)) + 1j * rng.standard_normal((m, 1, factor))
    bins = np.array([0, 4, 7, 17])
    w = lk.first_block_row_weights(n, factor, bins)
    direct = lk.frf_from_first_block_row(p1, factor)[bins, 0, 0]
    np.testing.assert_allclose(np.einsum("kj,kj->k", w, p1[bins % m, 0, :]), direct, atol=1e-13)


def test_first_block_row_refuses_wrong_column_count():
    with pytest.raises(ValueError, match="not a multiple of factor 2"):
        lk.frf_from_first_block_row(np.zeros((4, 1, 3)), 2)


@pytest.mark.parametrize("bad", [2.5, "2", True, 0, float("nan")])
def test_factor_must_be_a_whole_positive_number_never_truncated(bad):
    """int(2.5) lifted by 2 without a word; every kernel refuses such a factor, and 2.0
    (a whole float) still works like 2."""
    x = np.arange(8.0)
    calls = {
        "lift": lambda f: lk.lift(x, f),
        "lifted_spectrum_from_fast": lambda f: lk.lifted_spectrum_from_fast(x, f),
        "lifted_frf": lambda f: lk.lifted_frf(np.ones((8, 1, 1)), f),
        "frf_from_first_block_row": lambda f: lk.frf_from_first_block_row(np.ones((4, 1, 2)), f),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError, match="factor must be a positive integer"):
            call(bad)
        np.testing.assert_array_equal(call(2.0), call(2), err_msg=name)
