"""The output-error local rational model prototype (benchmarks/output_error_lrm.py).

Exact on a noiseless rational system; on noisy data its start is production's
least-squares fit, its result lowers the output-error criterion and is a stationary point
of it (checked against a per-bin real-parameter oracle gradient).
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from lcmr_xr.kernels.local_models import local_model

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def oe():
    spec = importlib.util.spec_from_file_location("bench_output_error_lrm",
                                                  BENCH / "output_error_lrm.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


M, N_HALF, DEGREES = 96, 8, (2, 1, 2)


def _rational_system(rng):
    """``Z = G(w) R`` with ``G_ip(w) = N_ip(w) / D_i(w)`` (degree 2 over degree 2 in the
    bin index ``w``, complex poles off the axis), random complex ``R``: exactly a local
    rational model of degrees (2, 1, 2) at every bin whose window does not wrap."""
    nr, nz = 2, 2
    w = np.arange(M, dtype=float)
    poles = np.array([[30 + 4j, 70 - 6j], [45 - 3j, 20 + 9j]])
    D = (w[:, None] - poles[None, :, 0]) * (w[:, None] - poles[None, :, 1])  # (M, nz)
    c = rng.standard_normal((3, nz, nr)) + 1j * rng.standard_normal((3, nz, nr))
    num = c[0] * 400 + c[1] * 20 * w[:, None, None] + c[2] * w[:, None, None] ** 2
    G = num / D[..., None]
    R = rng.standard_normal((M, nr)) + 1j * rng.standard_normal((M, nr))
    return R, np.einsum("kip,kp->ki", G, R), G


def test_noiseless_rational_system_is_recovered_exactly(oe):
    R, Z, G = _rational_system(np.random.default_rng(1))
    fit = oe.oe_local_model(R, Z, half_width=N_HALF, degrees=DEGREES, iterations=10)
    inner = slice(N_HALF, M - N_HALF)  # windows that do not wrap around the circle
    err = np.abs(fit["G"][inner] - G[inner]) / np.abs(G[inner])
    assert err.max() < 1e-9
    assert np.all(fit["cost"][inner] <= 1e-18 * np.sum(np.abs(Z) ** 2))
    # the start is production's least-squares fit
    lm = local_model(R, Z, half_width=N_HALF, degrees=DEGREES, covariance=None)
    np.testing.assert_allclose(fit["G_ls"][inner], lm.G[inner], rtol=1e-9)


def _oe_cost(Phi, X, z, theta, p):
    D = 1 + X @ theta[p:]
    return np.sum(np.abs(z - (Phi @ theta[:p]) / D) ** 2)


def test_noisy_fit_lowers_the_output_error_cost_to_a_stationary_point(oe):
    rng = np.random.default_rng(2)
    R, Z0, _ = _rational_system(rng)
    scale = 0.05 * np.sqrt(np.mean(np.abs(Z0) ** 2, axis=0))
    Z = Z0 + scale * (rng.standard_normal(Z0.shape) + 1j * rng.standard_normal(Z0.shape))
    fit = oe.oe_local_model(R, Z, half_width=N_HALF, degrees=DEGREES, iterations=200)
    lm = local_model(R, Z, half_width=N_HALF, degrees=DEGREES, covariance="full")
    np.testing.assert_allclose(fit["G_ls"], lm.G, rtol=1e-9, atol=1e-12 * np.abs(lm.G).max())
    # never above the least-squares solution's output-error cost, and well below it on most bins
    assert np.all(fit["cost"] <= fit["cost_ls"] * (1 + 1e-12))
    assert np.median(fit["cost"] / fit["cost_ls"]) < 0.9
    # stationary: the gradient of the OE cost (finite differences in the real and
    # imaginary parts of every parameter, an oracle independent of the prototype's
    # Jacobian) vanishes at the returned parameters, per bin and row
    nr, p = R.shape[-1], R.shape[-1] * (DEGREES[0] + 1) + DEGREES[1] + 1
    for k in (20, 41, 63):
        Rw, Zw = oe._windows(R, Z, np.array([k]), N_HALF)
        Phi, X = oe._basis(Rw, N_HALF, DEGREES)
        for i in range(Z.shape[-1]):
            theta, *_ = oe._oe_row(Phi, X, Zw[..., i], iterations=200)
            np.testing.assert_allclose(theta[0, :nr], fit["G"][k, i], rtol=1e-6)
            c0 = _oe_cost(Phi[0], X, Zw[0, :, i], theta[0], p)
            grad = []
            for j in range(theta.shape[-1]):
                for h in (1e-7, 1e-7j):
                    scale_j = h * max(1.0, abs(theta[0, j]))
                    tp, tm = theta[0].copy(), theta[0].copy()
                    tp[j] += scale_j
                    tm[j] -= scale_j
                    grad.append((_oe_cost(Phi[0], X, Zw[0, :, i], tp, p)
                                 - _oe_cost(Phi[0], X, Zw[0, :, i], tm, p)) / (2 * abs(scale_j))
                                * max(1.0, abs(theta[0, j])))
            assert np.max(np.abs(grad)) < 1e-5 * c0
    # the reported covariance is Hermitian and positive on the diagonal
    C = fit["G_cov"]
    np.testing.assert_allclose(C, np.conj(np.swapaxes(C, -1, -2)), atol=1e-12 * np.abs(C).max())
    assert np.all(np.real(np.einsum("kii->ki", C)) > 0)


def test_command_line_parses(oe, capsys):
    with pytest.raises(SystemExit) as exc:
        oe.main(["--help"])
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out
