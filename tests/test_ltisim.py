"""Tests of lcmr_xr.kernels.lti against independent computations and the loop oracle."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from _multirate_oracle import simulate_multirate_oracle
from lcmr_xr.kernels.lifting import lifted_frf
from lcmr_xr.kernels.lti import (StateSpace, block_diagonal, check_stable, continuous_zoh,
                                 dc_gain, frequency_response, hstack, lift_statespace,
                                 matched_notch, modal_zoh, multirate_closed_loop, notch_filter,
                                 series, simulate_lti, simulate_multirate, spectral_radius,
                                 static_gain, tf_q_inverse, vstack)


def random_system(rng, n, nu, ny, dt=1.0, rho=0.9, feedthrough=True, gain=1.0):
    """Random stable system with spectral radius ``rho``."""
    A = rng.standard_normal((n, n)) if n else np.zeros((0, 0))
    if n:
        A *= rho / spectral_radius(A)
    D = rng.standard_normal((ny, nu)) * gain if feedthrough else np.zeros((ny, nu))
    return StateSpace(A, rng.standard_normal((n, nu)) * gain, rng.standard_normal((ny, n)), D, dt)


def naive_simulation(sys, u, x0=None):
    """x(n+1) = A x + B u, y = C x + D u, one sample at a time (leading axes vectorised)."""
    lead, N = u.shape[:-2], u.shape[-2]
    x = np.zeros(lead + (sys.n_states,)) if x0 is None else np.array(x0, dtype=float)
    y = np.zeros(lead + (N, sys.n_outputs))
    for n in range(N):
        y[..., n, :] = x @ sys.C.T + u[..., n, :] @ sys.D.T
        x = x @ sys.A.T + u[..., n, :] @ sys.B.T
    return y


def markov_frf(sys, freqs, n_terms=4000):
    """FRF as the DTFT of the impulse response (needs a stable system)."""
    h = [sys.D]
    ab = sys.B
    for _ in range(n_terms):
        h.append(sys.C @ ab)
        ab = sys.A @ ab
    h = np.array(h)
    z = np.exp(-2j * np.pi * np.outer(freqs, np.arange(n_terms + 1)) * sys.dt)
    return np.einsum("fk,kab->fab", z, h)


def rel_err(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


# ----------------------------------------------------------------------------- state space


def test_statespace_checks_shapes_and_is_read_only():
    g = StateSpace(np.eye(2) * 0.5, np.ones((2, 1)), np.ones((1, 2)), [[0.0]], 0.1)
    assert (g.n_states, g.n_inputs, g.n_outputs) == (2, 1, 1)
    with pytest.raises(ValueError):
        g.A[0, 0] = 1.0
    with pytest.raises(ValueError, match="B has shape"):
        StateSpace(np.eye(2), np.ones((3, 1)), np.ones((1, 2)), [[0.0]], 0.1)
    with pytest.raises(ValueError, match="positive sampling period"):
        StateSpace(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), [[0.0]], 0.0)
    with pytest.raises(ValueError, match="NaN"):
        StateSpace([[np.nan]], [[1.0]], [[1.0]], [[0.0]], 1.0)


def closed_form_mode_zoh(k, f, z, dt):
    """Exact ZOH of k/(s^2 + 2 z w s + w^2) (underdamped, w > 0), written out by hand."""
    w = 2 * np.pi * f
    sigma, wd = z * w, w * np.sqrt(1 - z * z)
    e, c, s = np.exp(-sigma * dt), np.cos(wd * dt), np.sin(wd * dt)
    A = e * np.array([[c + sigma / wd * s, s / wd], [-w * w / wd * s, c - sigma / wd * s]])
    B = np.array([[(1 - e * (c + sigma / wd * s)) / w**2], [e * s / wd]])
    return A, B, np.array([[k, 0.0]])


def test_single_mode_zoh_matches_the_closed_form():
    dt = 1 / 100800
    freqs = np.array([10.0, 1234.0, 5300.0, 20000.0, 49000.0])
    zz = np.exp(2j * np.pi * freqs * dt)
    for k, f, z in [(2.0, 5300.0, 0.02), (-0.3, 44800.0, 0.3), (10.0, 100000.0, 0.3)]:
        A, B, C = closed_form_mode_zoh(k, f, z, dt)
        expected = np.array([(C @ np.linalg.solve(q * np.eye(2) - A, B))[0, 0] for q in zz])
        got = frequency_response(modal_zoh([k], [f], [z], dt), freqs)[:, 0, 0]
        np.testing.assert_allclose(got, expected, rtol=1e-11)
    # rigid body k/s^2: A = [[1, T], [0, 1]], B = [T^2/2, T]
    g = modal_zoh([3.0], [0.0], [0.0], dt)
    np.testing.assert_allclose(g.A, [[1.0, dt], [0.0, 1.0]], rtol=1e-15)
    np.testing.assert_allclose(g.B, [[dt * dt / 2], [dt]], rtol=1e-15)
    np.testing.assert_allclose(g.C, [[3.0, 0.0]])


def test_modal_zoh_agrees_with_scipy_on_a_well_scaled_system():
    # scipy's transfer-function route is accurate when w and dt are of order one
    k, w, z, dt = 2.0, 3.0, 0.1, 0.2
    num, den, _ = scipy.signal.cont2discrete(([k], [1.0, 2 * z * w, w * w]), dt, method="zoh")
    freqs = np.array([0.0, 0.3, 1.0, 2.4])
    zz = np.exp(2j * np.pi * freqs * dt)
    got = frequency_response(modal_zoh([k], [w / (2 * np.pi)], [z], dt), freqs)[:, 0, 0]
    np.testing.assert_allclose(got, np.polyval(num.ravel(), zz) / np.polyval(den, zz), rtol=1e-10)


def test_continuous_zoh_of_first_order_is_exact():
    a, dt = 3.0, 0.2
    g = continuous_zoh([[-a]], [[1.0]], [[2.0]], [[0.5]], dt)
    np.testing.assert_allclose(g.A, [[np.exp(-a * dt)]], rtol=1e-14)
    np.testing.assert_allclose(g.B, [[(1 - np.exp(-a * dt)) / a]], rtol=1e-14)
    np.testing.assert_allclose(dc_gain(g), [[2.0 / a + 0.5]], rtol=1e-13)


def test_continuous_zoh_is_the_block_exponential_and_the_integral_of_the_state_transition():
    # continuous_zoh delegates to scipy.signal.cont2discrete(method="zoh"); it must give
    # bit for bit the Van Loan block exponential exp([[A, B], [0, 0]] dt) it used to compute
    # itself, and Bd must be the integral int_0^dt exp(A s) ds B (checked by quadrature).
    import scipy.integrate

    rng = np.random.default_rng(11)
    for n, nu, dt in [(1, 1, 0.2), (3, 2, 0.05), (6, 3, 0.01)]:
        A = rng.standard_normal((n, n)) - 2 * np.eye(n)
        B = rng.standard_normal((n, nu))
        C, D = rng.standard_normal((2, n)), rng.standard_normal((2, nu))
        g = continuous_zoh(A, B, C, D, dt)
        big = np.zeros((n + nu, n + nu))
        big[:n, :n], big[:n, n:] = A * dt, B * dt
        e = scipy.linalg.expm(big)
        np.testing.assert_array_equal(g.A, e[:n, :n])
        np.testing.assert_array_equal(g.B, e[:n, n:])
        np.testing.assert_array_equal(g.C, C)
        np.testing.assert_array_equal(g.D, D)
        integral, _ = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(A * s) @ B, 0.0, dt,
                                               epsabs=1e-15, epsrel=1e-13)
        np.testing.assert_allclose(g.B, integral, rtol=1e-11, atol=1e-15)
        np.testing.assert_allclose(g.A, scipy.linalg.expm(A * dt), rtol=1e-12)


def test_tf_q_inverse_frf_matches_polynomial_ratio():
    num, den = [0.65, 0.020, -0.63], [1.0, -1.4, 0.51]
    g = tf_q_inverse(num, den, dt=1 / 50400)
    freqs = np.linspace(0, 25200, 37)
    qinv = np.exp(-2j * np.pi * freqs / 50400)
    expected = np.polyval(num[::-1], qinv) / np.polyval(den[::-1], qinv)
    np.testing.assert_allclose(frequency_response(g, freqs)[:, 0, 0], expected, rtol=1e-12)
    # unnormalised denominator and a longer numerator
    g2 = tf_q_inverse([1.0, 2.0, 3.0], [2.0, 0.5], dt=1.0)
    qinv = np.exp(-2j * np.pi * 0.1)
    np.testing.assert_allclose(frequency_response(g2, [0.1])[0, 0, 0],
                               (1 + 2 * qinv + 3 * qinv**2) / (2 + 0.5 * qinv), rtol=1e-12)
    np.testing.assert_allclose(tf_q_inverse([3.0], [2.0], dt=1.0).D, [[1.5]])  # static
    with pytest.raises(ValueError, match="a0 must be nonzero"):
        tf_q_inverse([1.0], [0.0, 1.0], dt=1.0)


def test_matched_notch_maps_poles_and_zeros_and_has_unit_dc_gain():
    dt, f, zn, zd = 1 / 100800, 21000.0, 0.01, 0.15
    g = matched_notch(f, zn, zd, dt)
    w = 2 * np.pi * f
    poles = np.exp(np.roots([1, 2 * zd * w, w * w]) * dt)
    zeros = np.exp(np.roots([1, 2 * zn * w, w * w]) * dt)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(g.A)), np.sort_complex(poles),
                               rtol=1e-12)
    np.testing.assert_allclose(dc_gain(g), [[1.0]], rtol=1e-12)
    # the FRF is K (z - z1)(z - z2) / ((z - p1)(z - p2)) with K fixing the DC gain
    zz = np.exp(2j * np.pi * np.array([100.0, 20000.0, 21000.0, 30000.0]) * dt)
    K = np.prod(1 - poles) / np.prod(1 - zeros)
    expected = K * np.prod(zz[:, None] - zeros, axis=1) / np.prod(zz[:, None] - poles, axis=1)
    np.testing.assert_allclose(frequency_response(g, [100.0, 20000.0, 21000.0, 30000.0])[:, 0, 0],
                               expected, rtol=1e-10)
    assert abs(frequency_response(g, [f])[0, 0, 0]) < 0.1  # a notch
    with pytest.raises(ValueError, match="Nyquist"):
        matched_notch(60000.0, 0.01, 0.1, dt)


def test_notch_filter_is_the_product_of_its_sections():
    dt = 1 / 100800
    rows = [(5650, .02, .09), (8000, .01, .02), (43300, .01, .05)]
    freqs = np.array([0.0, 5000.0, 8000.0, 40000.0])
    expected = np.prod([frequency_response(matched_notch(*row, dt), freqs) for row in rows], axis=0)
    np.testing.assert_allclose(frequency_response(notch_filter(rows, dt), freqs), expected,
                               rtol=1e-10)
    np.testing.assert_allclose(frequency_response(notch_filter([], dt), freqs)[:, 0, 0], 1.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n1=st.integers(0, 4), n2=st.integers(0, 4),
       nu=st.integers(1, 3), nm=st.integers(1, 3), ny=st.integers(1, 3))
def test_interconnections_match_frf_algebra(seed, n1, n2, nu, nm, ny):
    rng = np.random.default_rng(seed)
    g1, g2 = random_system(rng, n1, nu, nm), random_system(rng, n2, nm, ny)
    f = np.array([0.0, 0.07, 0.31, 0.5])
    h1, h2 = frequency_response(g1, f), frequency_response(g2, f)
    np.testing.assert_allclose(frequency_response(series(g1, g2), f), h2 @ h1, rtol=1e-9,
                               atol=1e-12)
    g3 = random_system(rng, n2, nu, nm)
    h3 = frequency_response(g3, f)
    np.testing.assert_allclose(frequency_response(vstack(g1, g3), f),
                               np.concatenate([h1, h3], axis=1), rtol=1e-9, atol=1e-12)
    g4 = random_system(rng, n2, nm, nm)
    h4 = frequency_response(g4, f)
    np.testing.assert_allclose(frequency_response(hstack(g3, g4), f),
                               np.concatenate([h3, h4], axis=2), rtol=1e-9, atol=1e-12)
    bd = frequency_response(block_diagonal(g1, g2), f)
    np.testing.assert_allclose(bd[:, :nm, :nu], h1, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(bd[:, nm:, nu:], h2, rtol=1e-9, atol=1e-12)
    assert not np.any(bd[:, :nm, nu:]) and not np.any(bd[:, nm:, :nu])


def test_interconnection_refuses_mismatches():
    a, b = static_gain(np.ones((2, 1)), 1.0), static_gain(np.ones((1, 3)), 1.0)
    with pytest.raises(ValueError, match="2 outputs cannot feed one with 3 inputs"):
        series(a, b)
    with pytest.raises(ValueError, match="sampling periods"):
        series(static_gain(1.0, 1.0), static_gain(1.0, 2.0))


def test_stacks_are_the_block_matrices_of_their_parts():
    # hstack: [A1 0; 0 A2], [B1 0; 0 B2], [C1 C2], [D1 D2]; vstack: [A1 0; 0 A2], [B1; B2],
    # [C1 0; 0 C2], [D1; D2] -- exactly, since both are built from block_diagonal and a
    # static summer or splitter in series.
    rng = np.random.default_rng(5)
    g1, g2 = random_system(rng, 2, 2, 3), random_system(rng, 3, 1, 3)
    h = hstack(g1, g2)
    bd = scipy.linalg.block_diag
    np.testing.assert_array_equal(h.A, bd(g1.A, g2.A))
    np.testing.assert_array_equal(h.B, bd(g1.B, g2.B))
    np.testing.assert_array_equal(h.C, np.hstack([g1.C, g2.C]))
    np.testing.assert_array_equal(h.D, np.hstack([g1.D, g2.D]))
    g3, g4 = random_system(rng, 2, 2, 3), random_system(rng, 0, 2, 1)
    v = vstack(g3, g4)
    np.testing.assert_array_equal(v.A, bd(g3.A, g4.A))
    np.testing.assert_array_equal(v.B, np.vstack([g3.B, g4.B]))
    np.testing.assert_array_equal(v.C, bd(g3.C, g4.C))
    np.testing.assert_array_equal(v.D, np.vstack([g3.D, g4.D]))
    with pytest.raises(ValueError,
                       match="hstack: every system must have the same number of outputs"):
        hstack(g1, g4)
    with pytest.raises(ValueError,
                       match="vstack: every system must have the same number of inputs"):
        vstack(g1, g2)
    with pytest.raises(ValueError, match="at least one system"):
        vstack()


def test_frequency_response_equals_dtft_of_impulse_response():
    rng = np.random.default_rng(3)
    g = random_system(rng, 6, 2, 3, dt=0.01, rho=0.8)
    f = np.linspace(0, 50, 23)
    np.testing.assert_allclose(frequency_response(g, f, chunk=5), markov_frf(g, f), rtol=1e-10,
                               atol=1e-12)


# ----------------------------------------------------------------------------- lifting


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), factor=st.integers(1, 4), n=st.integers(0, 5),
       nu=st.integers(1, 2), ny=st.integers(1, 2), m=st.integers(2, 6))
def test_lifted_statespace_frf_equals_lifted_frf_identity(seed, factor, n, nu, ny, m):
    rng = np.random.default_rng(seed)
    g = random_system(rng, n, nu, ny, dt=0.5, rho=0.95)
    N = m * factor
    fast = frequency_response(g, np.arange(N) / (N * g.dt))
    lifted = lift_statespace(g, factor)
    assert lifted.dt == factor * g.dt
    slow = frequency_response(lifted, np.arange(m) / (m * lifted.dt))
    np.testing.assert_allclose(slow, lifted_frf(fast, factor), rtol=1e-9, atol=1e-11)


def test_lifted_statespace_simulates_the_lifted_signals():
    rng = np.random.default_rng(7)
    g, F, N = random_system(rng, 4, 2, 3), 3, 60
    u = rng.standard_normal((N, 2))
    y = naive_simulation(g, u)
    y_bar = naive_simulation(lift_statespace(g, F), u.reshape(N // F, F * 2))
    np.testing.assert_allclose(y_bar, y.reshape(N // F, F * 3), rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------- simulation


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 6), nu=st.integers(1, 3),
       ny=st.integers(1, 3), N=st.integers(1, 200), block=st.sampled_from([None, 1, 7, 16, 500]))
def test_simulate_lti_matches_naive_recursion(seed, n, nu, ny, N, block):
    rng = np.random.default_rng(seed)
    g = random_system(rng, n, nu, ny, rho=0.97)
    u = rng.standard_normal((2, N, nu))
    x0 = rng.standard_normal((2, n))
    y = simulate_lti(g, u, x0, block_length=block)
    assert y.shape == (2, N, ny)
    np.testing.assert_allclose(y, naive_simulation(g, u, x0), rtol=1e-11,
                               atol=1e-11 * np.abs(y).max())


def test_simulate_lti_is_accurate_over_long_records_and_marginal_systems():
    # double integrator (unbounded growth) and a lightly damped mode, 2**14 samples
    g = modal_zoh([1.0, 3.0], [0.0, 20.0], [0.0, 0.001], dt=1e-3)
    u = np.random.default_rng(0).standard_normal((2**14, 1))
    y = simulate_lti(g, u)
    assert rel_err(y, naive_simulation(g, u)) < 1e-12


def test_simulate_lti_refuses_wrong_input_shape():
    g = static_gain(np.ones((1, 2)), 1.0)
    with pytest.raises(ValueError, match=r"\(\.\.\., N, 2\)"):
        simulate_lti(g, np.ones((10, 3)))
    with pytest.raises(ValueError, match="block_length"):
        simulate_lti(g, np.ones((10, 2)), block_length=0)


def test_stability_checks():
    assert spectral_radius([[0.5, 1.0], [0.0, -0.9]]) == pytest.approx(0.9)
    assert spectral_radius(np.zeros((0, 0))) == 0.0
    with pytest.raises(ValueError, match=r"largest \|eigenvalue\| 1\.1 >= 1\. check this"):
        check_stable(tf_q_inverse([1.0], [1.0, -1.1], 1.0), "test loop", "check this")


# ----------------------------------------------------------------------------- multirate loop


def _loop_case(rng, n_p, nu, ny, F, plant_feedthrough):
    """Random plant, controller and filter whose multirate loop is stable (redrawn until so)."""
    while True:
        plant = random_system(rng, n_p, nu, ny, dt=0.1, rho=0.9, feedthrough=plant_feedthrough)
        controller = random_system(rng, 2, ny, nu, dt=0.1 * F, rho=0.5, gain=0.05)
        filt = random_system(rng, 2, nu, nu, dt=0.1, rho=0.6)
        loop = multirate_closed_loop(plant, controller, filt, F, check_stability=False)
        if loop.spectral_radius < 0.98:
            return plant, controller, filt


@pytest.mark.parametrize("F, nu, ny, plant_feedthrough, use_filter",
                         [(2, 1, 1, False, True), (3, 2, 2, True, True), (3, 2, 1, True, False),
                          (4, 1, 2, True, True)])
def test_multirate_loop_matches_oracle(F, nu, ny, plant_feedthrough, use_filter):
    rng = np.random.default_rng(F * 10 + nu + ny)
    plant, controller, filt = _loop_case(rng, 4, nu, ny, F, plant_feedthrough)
    filt = filt if use_filter else None
    loop = multirate_closed_loop(plant, controller, filt, F)
    N = 60 * F
    r, d_u = rng.standard_normal((N, nu)), rng.standard_normal((N, nu))
    d_y, ref = rng.standard_normal((N, ny)), rng.standard_normal((N // F, ny))
    expected = simulate_multirate_oracle(plant, controller, filt, F, r, d_u, d_y, ref)
    got = simulate_multirate(loop, r, d_u, d_y, ref)
    for a, b in zip(got, expected):
        assert a.shape == b.shape
        assert rel_err(a, b) < 1e-10
    np.testing.assert_array_equal(got.y_slow.shape, (N // F, ny))
    np.testing.assert_allclose(got.y_slow, got.y[::F], rtol=1e-12, atol=1e-14)


def test_algebraic_loop_is_solved_not_ignored():
    # Static plant, filter and controller: y_l = Dp (Df Dc (ref - y_l) + r) solves to a
    # closed form; ignoring the loop (a stale v) would give a different value.
    F, dp, df, dc = 2, 0.5, 2.0, 0.3
    plant, filt = static_gain(dp, 1.0), static_gain(df, 1.0)
    controller = static_gain(dc, float(F))
    loop = multirate_closed_loop(plant, controller, filt, F)
    r = np.array([[1.0], [0.0], [2.0], [0.0]])
    ref = np.array([[0.5], [-1.0]])
    out = simulate_multirate(loop, r, reference=ref)
    gain = dp * df * dc
    expected = (dp * r[::F, 0] + gain * ref[:, 0]) / (1 + gain)
    np.testing.assert_allclose(out.y_slow[:, 0], expected, rtol=1e-14)


def test_multirate_loop_broadcasts_over_leading_axes():
    rng = np.random.default_rng(11)
    plant, controller, filt = _loop_case(rng, 3, 2, 1, 2, True)
    loop = multirate_closed_loop(plant, controller, filt, 2)
    r = rng.standard_normal((3, 40, 2))
    d_y = rng.standard_normal((40, 1))  # shared by the three experiments
    got = simulate_multirate(loop, r, d_y=d_y)
    assert got.u.shape == (3, 40, 2) and got.y_slow.shape == (3, 20, 1)
    for i in range(3):
        one = simulate_multirate(loop, r[i], d_y=d_y)
        np.testing.assert_allclose(got.y[i], one.y, rtol=1e-12, atol=1e-15)


def test_unstable_loop_is_refused_with_a_clear_message():
    # P = 1/(q - 1) (integrator), C = k: closed loop pole 1 - k F-ish; k large is unstable
    plant = tf_q_inverse([0.0, 1.0], [1.0, -1.0], dt=1.0)
    with pytest.raises(ValueError) as err:
        multirate_closed_loop(plant, static_gain(3.0, 2.0), None, 2)
    msg = str(err.value)
    assert "multirate closed loop" in msg and "|eigenvalue|" in msg and "controller sign" in msg
    # the same loop with a small gain is stable, and the check can be switched off
    assert multirate_closed_loop(plant, static_gain(0.2, 2.0), None, 2).spectral_radius < 1
    loop = multirate_closed_loop(plant, static_gain(3.0, 2.0), None, 2, check_stability=False)
    assert loop.spectral_radius > 1
    # positive feedback (wrong controller sign) is refused too
    with pytest.raises(ValueError, match="unstable"):
        multirate_closed_loop(plant, static_gain(-0.2, 2.0), None, 2)


def test_multirate_loop_refuses_bad_parts():
    plant = tf_q_inverse([0.0, 1.0], [1.0, -0.5], dt=1.0)
    with pytest.raises(ValueError, match="discretise the controller at 2.0 s"):
        multirate_closed_loop(plant, static_gain(0.1, 1.0), None, 2)
    with pytest.raises(ValueError, match="filter sits between the controller and the 1 plant inputs"):
        multirate_closed_loop(plant, static_gain(0.1, 2.0), static_gain(np.eye(2), 1.0), 2)
    with pytest.raises(ValueError, match="needs 1 inputs and 1 outputs; got 1 inputs and 2"):
        multirate_closed_loop(plant, static_gain(np.ones((2, 1)), 2.0), None, 2)
    with pytest.raises(ValueError, match="ill-posed algebraic loop"):
        multirate_closed_loop(static_gain(1.0, 1.0), static_gain(-1.0, 2.0), None, 2)
    loop = multirate_closed_loop(plant, static_gain(0.1, 2.0), None, 2)
    with pytest.raises(ValueError, match="trim r to 4 samples"):
        simulate_multirate(loop, np.ones((5, 1)))
    with pytest.raises(ValueError, match="reference must have shape"):
        simulate_multirate(loop, np.ones((4, 1)), reference=np.ones((4, 1)))


def test_frequency_response_on_a_pole_is_infinite_not_an_error():
    g = block_diagonal(tf_q_inverse([0.0, 1.0], [1.0, -1.0], 1.0), static_gain(2.0, 1.0))
    h = frequency_response(g, [0.0, 0.25])
    assert np.all(np.isinf(h[0]))  # the whole (singular) frequency is infinite
    np.testing.assert_allclose(h[1, 0, 0], 1 / (1j - 1), rtol=1e-14)
    np.testing.assert_allclose(h[1, 1, 1], 2.0)
