"""Disturbances of the HDD benchmark: fan vibration, rotational vibration, repeatable run-out.

Approximation (documented as the benchmark file allows): the benchmark draws white noise
uniform on [-0.5, 0.5] at ``Tsc = Ts/20 = Th/10`` and discretises the shaping filters with
ZOH at ``Tsc``.  Here noise and filters run at the fast period ``Th`` directly.  Noise held
over ``Th`` has ten times the spectral density of noise held over ``Th/10`` (the density of
held white noise is its variance times the hold time), so its amplitude is scaled by
``sqrt(1/10)``: the disturbance spectra below the fast Nyquist frequency then match the
benchmark's (the fan vibration has a standard deviation of 3.0 nm, benchmark about 2.9 nm).

Every shaping filter starts in its stationary state (initial state drawn from the
stationary covariance, a discrete Lyapunov equation), so the disturbances are stationary
from the first sample instead of growing in over tens of milliseconds.
"""

from __future__ import annotations

import functools

import numpy as np

from lcmr_xr.hdd.plants import FAST_PERIOD
from lcmr_xr.kernels.excitation import check_rng
from lcmr_xr.kernels.lti import StateSpace, continuous_zoh, modal_zoh, simulate_lti

#: Fan-vibration modes (k, zeta, f Hz) of ``sum k / (s^2 + 2 zeta w s + w^2)``.
FAN_MODES = ((0.6, .008, 2200), (0.3, .005, 2937), (1, .005, 3300), (0.5, .005, 3545),
             (0.3, .002, 3980), (1, .01, 4220), (1, .008, 4380), (0.5, .002, 5072),
             (2, .003, 5370), (15, .04, 5850), (10, .008, 6660), (1.5, .003, 7670),
             (2.5, .07, 9200))
#: Amplitude scale of white noise held over Th instead of Tsc = Th/10 (see module docstring).
NOISE_SCALE = np.sqrt(1.0 / 10.0)
#: Standard deviation of uniform noise on [-0.5, 0.5] before NOISE_SCALE.
UNIFORM_STD = np.sqrt(1.0 / 12.0)
#: Repeatable run-out: samples per revolution, amplitude per harmonic (m), harmonics 1..209.
RRO_PERIOD = 420
RRO_AMPLITUDE = 0.05e-9
RRO_HARMONICS = np.arange(1, RRO_PERIOD // 2)


@functools.lru_cache(maxsize=None)
def fan_filter() -> StateSpace:
    """Shaping filter of the fan vibration (13 modes, block-diagonal modal form, ZOH at ``Th``).

    Examples
    --------
    >>> fan_filter().n_states
    26
    """
    k, z, f = np.array(FAN_MODES, dtype=float).T
    return modal_zoh(k, f, z, FAST_PERIOD)


@functools.lru_cache(maxsize=None)
def rotational_filter() -> StateSpace:
    """Shaping filter of the rotational vibration, ZOH at ``Th``.

    ``3e-10 (s + 2 pi 50)/(s + 2 pi 3) * (s^2 + 2*20*w1 s + w1^2)/(s^2 + 2*0.1*w2 s + w2^2)``
    with ``w1 = 2 pi 2000``, ``w2 = 2 pi 250``; each factor is written as ``1 + strictly
    proper part`` and the cascade is discretised as one 3-state system.

    Examples
    --------
    >>> rotational_filter().n_states
    3
    """
    a, b = 2 * np.pi * 50, 2 * np.pi * 3
    w1, w2, zn, zd = 2 * np.pi * 2000, 2 * np.pi * 250, 20.0, 0.1
    # first factor: (s + a)/(s + b) = 1 + (a - b)/(s + b), state x1
    # second factor (input y1 = (a - b) x1 + u): controllable form in x2 = [q, dq/dt]
    a2 = np.array([[0.0, 1.0], [-w2 * w2, -2 * zd * w2]])
    b2 = np.array([[0.0], [1.0]])
    c2 = np.array([[w1 * w1 - w2 * w2, 2 * zn * w1 - 2 * zd * w2]])
    A = np.zeros((3, 3))
    A[0, 0] = -b
    A[1:, 0:1] = b2 * (a - b)
    A[1:, 1:] = a2
    B = np.vstack([[[1.0]], b2])
    C = 3e-10 * np.hstack([[[a - b]], c2])
    return continuous_zoh(A, B, C, [[3e-10]], FAST_PERIOD)


def stationary_std(sys: StateSpace, noise_std: float) -> np.ndarray:
    """Standard deviation of each output of a stable system driven by white noise.

    Parameters
    ----------
    sys : StateSpace
        Stable system with one input.
    noise_std : float
        Standard deviation of the white input noise.

    Returns
    -------
    ndarray, shape (ny,)
        ``sqrt(diag(C P C^T + s^2 D D^T))`` with ``P = A P A^T + s^2 B B^T``.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> round(float(stationary_std(tf_q_inverse([1.0], [1.0, -0.6], 1.0), 1.0)[0]), 6)
    1.25
    """
    p = _stationary_state_covariance(sys, noise_std)
    cov = sys.C @ p @ sys.C.T + noise_std**2 * sys.D @ sys.D.T
    return np.sqrt(np.diag(cov))


def _stationary_state_covariance(sys: StateSpace, noise_std: float) -> np.ndarray:
    # P = sum_k A^k Q A^k^T by doubling (Smith): P <- P + A^m P A^m^T, A^m <- (A^m)^2.
    # Exact to rounding for these stable modal systems, whereas the Kronecker solve suffers
    # from the modal state scaling (1/w^2 next to w) and the default bilinear method perturbs
    # lightly damped pairs.
    p = noise_std**2 * sys.B @ sys.B.T
    a_m = sys.A
    for _ in range(64):  # covers 2^64 samples: any stable filter has converged
        p = p + a_m @ p @ a_m.T
        a_m = a_m @ a_m
        if not np.any(np.abs(a_m) > 1e-30):
            return p
    raise ValueError("the shaping filter is not stable: its stationary covariance diverges.")


@functools.lru_cache(maxsize=None)
def _stationary_state_factor(filter_name: str) -> tuple[StateSpace, np.ndarray]:
    # Cached per filter (systems are immutable): the covariance, and a factor L with
    # L L^T = P so that L @ N(0, I) is a stationary initial state.
    sys = {"fan": fan_filter, "rotational": rotational_filter}[filter_name]()
    cov = _stationary_state_covariance(sys, NOISE_SCALE * UNIFORM_STD)
    vals, vecs = np.linalg.eigh((cov + cov.T) / 2)
    return sys, vecs * np.sqrt(np.clip(vals, 0.0, None))


def _shaped_uniform_noise(filter_name: str, n_samples: int, rng: np.random.Generator) -> np.ndarray:
    sys, factor = _stationary_state_factor(filter_name)
    noise = NOISE_SCALE * rng.uniform(-0.5, 0.5, size=(int(n_samples), 1))
    x0 = factor @ rng.standard_normal(sys.n_states)
    return simulate_lti(sys, noise, x0)[:, 0]


def fan_vibration(n_samples: int, rng: np.random.Generator) -> np.ndarray:
    """Fan-induced vibration ``d_p`` of the head position (m) at ``Th``, stationary.

    Uniform white noise on [-0.5, 0.5], scaled by ``sqrt(1/10)`` (module docstring), through
    :func:`fan_filter`; standard deviation 3.0 nm.

    Parameters
    ----------
    n_samples : int
        Number of fast samples.
    rng : numpy.random.Generator
        Source of randomness (``numpy.random.default_rng(seed)`` for reproducibility).

    Returns
    -------
    ndarray, shape (n_samples,)
        In m.

    Examples
    --------
    >>> d = fan_vibration(1000, np.random.default_rng(0))
    >>> d.shape
    (1000,)
    """
    check_rng(rng)
    return _shaped_uniform_noise("fan", n_samples, rng)


def rotational_vibration(n_samples: int, rng: np.random.Generator) -> np.ndarray:
    """Rotational vibration ``d_f`` at the VCM input (VCM input units) at ``Th``, stationary.

    Uniform white noise on [-0.5, 0.5], scaled by ``sqrt(1/10)``, through
    :func:`rotational_filter`.

    Parameters
    ----------
    n_samples : int
        Number of fast samples.
    rng : numpy.random.Generator
        Source of randomness.

    Returns
    -------
    ndarray, shape (n_samples,)

    Examples
    --------
    >>> rotational_vibration(10, np.random.default_rng(0)).shape
    (10,)
    """
    check_rng(rng)
    return _shaped_uniform_noise("rotational", n_samples, rng)


def repeatable_runout(n_slow_samples: int, rng: np.random.Generator) -> np.ndarray:
    """Repeatable run-out ``d_RRO`` (m) at the slow period ``Tl``, periodic with one revolution.

    420 samples per revolution (120 Hz), amplitude 0.05 nm on every harmonic 1..209
    (120 Hz ... 25.08 kHz), nothing at DC and Nyquist, random phases; standard deviation
    ``0.05 nm sqrt(209/2) = 0.511 nm`` over whole revolutions.

    Parameters
    ----------
    n_slow_samples : int
        Number of slow samples.
    rng : numpy.random.Generator
        Source of randomness (phases).

    Returns
    -------
    ndarray, shape (n_slow_samples,)
        In m; the revolution repeats (``d[l + 420] == d[l]``).

    Examples
    --------
    >>> d = repeatable_runout(840, np.random.default_rng(0))
    >>> bool(np.allclose(d[:420], d[420:]))
    True
    """
    check_rng(rng)
    spectrum = np.zeros(RRO_PERIOD // 2 + 1, dtype=complex)
    phases = rng.uniform(0, 2 * np.pi, RRO_HARMONICS.size)
    # irfft of (N/2) a e^{j phi} on harmonic h gives a cos(2 pi h l / N + phi)
    spectrum[RRO_HARMONICS] = RRO_PERIOD / 2 * RRO_AMPLITUDE * np.exp(1j * phases)
    revolution = np.fft.irfft(spectrum, n=RRO_PERIOD)
    return np.resize(revolution, int(n_slow_samples))

