"""Periodic multisine excitations, on plain numpy arrays.

No labels here.  Signals are returned as ``(..., n_samples, n_channels)``: time on the
second-to-last axis, channels last, optional leading axes (experiments) first.

Conventions shared by every generator in this module:

* ``bins`` are fast DFT bins ``k`` of one period of ``N = n_samples`` samples, the
  frequency of bin ``k`` is ``k / (N Ts)``.  Allowed: ``1 <= k <= N // 2``, unique.
  DC (``k = 0``) is never excited: a closed-loop identification experiment has no use for
  a constant offset, and a DC term would have to be real, which breaks the random-phase
  design.
* The amplitude is flat *in the DFT*: ``|numpy.fft.fft(x, axis=-2)[k]|`` is the same on every
  excited bin (and on their mirror bins ``N - k``), and exactly zero on every other bin.
* The Nyquist bin ``k = N/2`` (even ``N`` only) can only carry a real coefficient, so when it
  is excited its component is ``+-A`` with a random (or, for Schroeder phases, a
  deterministic) sign.  In the time domain it is ``(+-A / N) (-1)^n``, half the amplitude of
  a cosine on another bin, because it has no mirror bin.
* ``rms`` is met exactly: each channel is scaled after synthesis so that
  ``sqrt(mean(x**2))`` over one period equals the requested value.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "check_bins",
    "check_rng",
    "crest_factor",
    "multisine_from_phasors",
    "orthogonal_random_phase_multisines",
    "random_phase_multisine",
    "schroeder_multisine",
    "schroeder_phases",
]


def check_rng(rng) -> None:
    """Refuse anything but a ``numpy.random.Generator`` (seeds are the caller's business).

    Parameters
    ----------
    rng : numpy.random.Generator
        The random generator to check.

    Raises
    ------
    TypeError
        If ``rng`` is not a ``numpy.random.Generator``; the message names the remedy.

    Examples
    --------
    >>> check_rng(np.random.default_rng(0))
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; "
            "pass numpy.random.default_rng(seed)."
        )


def check_bins(n_samples: int, bins) -> np.ndarray:
    """Validate excited DFT bins and return them sorted as an int64 array.

    Parameters
    ----------
    n_samples : int
        Samples in one period, ``N >= 2``.
    bins : array_like of int
        Excited bins; each in ``1..N//2``, no duplicates, at least one.

    Returns
    -------
    ndarray of int64, shape (K,)
        The bins, sorted ascending.

    Examples
    --------
    >>> check_bins(8, [3, 1, 4])
    array([1, 3, 4])
    """
    n_samples = int(n_samples)
    if n_samples < 2:
        raise ValueError(
            f"a multisine needs at least 2 samples per period, got n_samples={n_samples}; "
            "use a longer period."
        )
    raw = np.asarray(bins)
    if raw.ndim != 1 or raw.size == 0:
        raise ValueError(
            f"bins must be a non-empty 1-d array of DFT bin indices, got shape {raw.shape}; "
            "pass e.g. np.arange(1, n_samples // 2 + 1)."
        )
    if not np.issubdtype(raw.dtype, np.integer):
        if np.issubdtype(raw.dtype, np.floating) and np.all(raw == np.round(raw)):
            raw = raw.astype(np.int64)
        else:
            raise ValueError(
                f"bins must be integers (DFT bin indices), got dtype {raw.dtype}; "
                "convert frequencies f to bins with round(f * n_samples * sampling_period)."
            )
    out = np.sort(raw.astype(np.int64))
    lo, hi = 1, n_samples // 2
    bad = out[(out < lo) | (out > hi)]
    if bad.size:
        raise ValueError(
            f"bins {bad.tolist()} are outside 1..{hi} (N={n_samples}); DC (0) is never excited "
            f"and bins above N//2 are mirror images of bins N-k. Keep only bins in 1..{hi}."
        )
    if np.any(np.diff(out) == 0):
        dup = np.unique(out[1:][np.diff(out) == 0])
        raise ValueError(f"bins contain duplicates {dup.tolist()}; pass each bin once (np.unique).")
    return out


def _check_rms(rms, n_channels: int) -> np.ndarray:
    r = np.asarray(rms, dtype=float)
    if r.ndim == 0:
        r = np.full(n_channels, float(r))
    if r.shape != (n_channels,):
        raise ValueError(
            f"rms must be a scalar or one value per channel (shape ({n_channels},)), "
            f"got shape {r.shape}."
        )
    if not np.all(np.isfinite(r) & (r > 0)):
        raise ValueError(f"rms must be finite and positive, got {r.tolist()}.")
    return r


def _check_channels(n_channels: int) -> int:
    n_channels = int(n_channels)
    if n_channels < 1:
        raise ValueError(f"n_channels must be at least 1, got {n_channels}.")
    return n_channels


def multisine_from_phasors(n_samples: int, bins, phasors, rms) -> np.ndarray:
    """Real periodic signal with the given DFT coefficients on ``bins``, scaled to ``rms``.

    Parameters
    ----------
    n_samples : int
        Samples in one period ``N``.
    bins : array_like of int, shape (K,)
        Excited bins, see :func:`check_bins` (must already be sorted to match ``phasors``).
    phasors : array_like of complex, shape (..., K, C)
        DFT coefficients on the excited bins (any nonzero magnitude; the overall scale is
        set by ``rms``).  At the Nyquist bin only the real part is used.
    rms : float or array_like, shape (C,)
        Root mean square of each channel over one period, in the signal's unit.

    Returns
    -------
    ndarray of float, shape (..., N, C)
        Every leading index (experiment) and channel has exactly the requested rms.

    Examples
    --------
    >>> x = multisine_from_phasors(8, [2], np.ones((1, 1)), 1.0)
    >>> np.round(x[:, 0], 4).tolist() == [1.4142, 0, -1.4142, 0, 1.4142, 0, -1.4142, 0]
    True
    """
    bins = np.asarray(bins, dtype=np.int64)
    ph = np.asarray(phasors, dtype=complex)
    if ph.ndim < 2 or ph.shape[-2] != bins.size:
        raise ValueError(
            f"phasors must have shape (..., K, C) with K={bins.size} bins, got {ph.shape}."
        )
    n_channels = ph.shape[-1]
    r = _check_rms(rms, n_channels)
    spectrum = np.zeros(ph.shape[:-2] + (n_samples // 2 + 1, n_channels), dtype=complex)
    spectrum[..., bins, :] = ph
    if n_samples % 2 == 0 and bins.size and bins[-1] == n_samples // 2:
        # irfft would silently drop the imaginary part; do it here so the caller sees it.
        spectrum[..., -1, :] = spectrum[..., -1, :].real
    x = np.fft.irfft(spectrum, n=n_samples, axis=-2)
    current = np.sqrt(np.mean(x**2, axis=-2, keepdims=True))
    if np.any(current == 0):
        raise ValueError("a channel has an all-zero spectrum; every phasor must be nonzero.")
    return x * (r / current)


def random_phase_multisine(n_samples: int, n_channels: int, bins, rms, rng) -> np.ndarray:
    """One period of a random-phase multisine per channel, independent over channels.

    Parameters
    ----------
    n_samples : int
        Samples in one period ``N``.
    n_channels : int
        Number of channels ``C``; each gets its own independent phases.
    bins : array_like of int
        Excited fast DFT bins in ``1..N//2`` (DC excluded).  If ``N/2`` is among them its
        component is real with a random sign.
    rms : float or array_like, shape (C,)
        Exact rms of each channel over one period, in the signal's unit.
    rng : numpy.random.Generator
        Source of the phases (uniform on ``[0, 2 pi)``); pass
        ``numpy.random.default_rng(seed)`` for reproducibility.

    Returns
    -------
    ndarray of float, shape (N, C)
        Flat DFT amplitude on ``bins``, exactly zero on all other bins.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x = random_phase_multisine(64, 2, np.arange(1, 11), [1.0, 0.5], rng)
    >>> x.shape, np.round(np.sqrt(np.mean(x**2, axis=0)), 12).tolist()
    ((64, 2), [1.0, 0.5])
    """
    n_channels = _check_channels(n_channels)
    bins = check_bins(n_samples, bins)
    check_rng(rng)
    phasors = np.exp(2j * np.pi * rng.random((bins.size, n_channels)))
    if n_samples % 2 == 0 and bins[-1] == n_samples // 2:
        phasors[-1] = rng.choice([-1.0, 1.0], size=n_channels)
    return multisine_from_phasors(n_samples, bins, phasors, rms)


def schroeder_phases(n_bins: int) -> np.ndarray:
    """Schroeder phases ``phi_k = -k (k - 1) pi / K`` for ``k = 1..K`` flat components, in rad.

    Parameters
    ----------
    n_bins : int
        Number of equal-amplitude components ``K``.

    Returns
    -------
    ndarray of float, shape (K,)
        Phases in rad; they keep the crest factor of a flat multisine low (about 1.7).

    Examples
    --------
    >>> [round(float(p), 4) for p in schroeder_phases(3)][1:]
    [-2.0944, -6.2832]
    """
    k = np.arange(1, int(n_bins) + 1)
    return -k * (k - 1) * np.pi / n_bins


def schroeder_multisine(n_samples: int, n_channels: int, bins, rms) -> np.ndarray:
    """One period of a Schroeder-phased multisine (low crest factor), same on every channel.

    Parameters
    ----------
    n_samples : int
        Samples in one period ``N``.
    n_channels : int
        Number of channels; all get the same deterministic phases (scaled to their rms).
    bins : array_like of int
        Excited bins in ``1..N//2``; phase ``k`` of :func:`schroeder_phases` goes to the
        ``k``-th excited bin.  At the Nyquist bin the component is real with the sign of
        ``cos(phi)``.
    rms : float or array_like, shape (C,)
        Exact rms of each channel over one period.

    Returns
    -------
    ndarray of float, shape (N, C)
        Flat DFT amplitude on ``bins``, exactly zero elsewhere, exact rms per channel.

    Examples
    --------
    >>> x = schroeder_multisine(256, 1, np.arange(1, 101), 1.0)
    >>> bool(crest_factor(x, axis=0)[0] < 2.0)
    True
    """
    n_channels = _check_channels(n_channels)
    bins = check_bins(n_samples, bins)
    phi = schroeder_phases(bins.size)
    phasors = np.exp(1j * phi)
    if n_samples % 2 == 0 and bins[-1] == n_samples // 2:
        phasors[-1] = 1.0 if np.cos(phi[-1]) >= 0 else -1.0
    phasors = np.repeat(phasors[:, None], n_channels, axis=1)
    return multisine_from_phasors(n_samples, bins, phasors, rms)


def _hadamard(n: int) -> np.ndarray | None:
    """Sylvester Hadamard matrix of order ``n`` (a power of two), else ``None``."""
    if n < 1 or n & (n - 1):
        return None
    h = np.ones((1, 1))
    while h.shape[0] < n:
        h = np.block([[h, h], [h, -h]])
    return h


def orthogonal_random_phase_multisines(
    n_samples: int, n_channels: int, bins, rms, rng
) -> np.ndarray:
    """Orthogonal random-phase multisines for a multi-experiment MIMO design.

    ``n_exp = n_channels`` experiments.  At each excited bin ``k`` the matrix of input
    spectra ``U(k)[e, c]`` (experiment ``e``, channel ``c``) is ``T D(k)``: ``T`` is the
    ``C x C`` DFT matrix ``T[e, c] = exp(-2j pi e c / C)`` and ``D(k)`` a diagonal of
    independent random phases per channel and bin (Dobrowiecki, Schoukens and
    Guillaume, IEEE TIM 2006).  So experiment 0 holds independent random-phase multisines,
    and experiment ``e`` rotates channel ``c`` by ``exp(-2j pi e c / C)`` on every bin.
    Hence ``U(k)^H U(k) = U(k) U(k)^H = C A^2 I``: the experiments are orthogonal at every
    bin, and every channel of every experiment has a flat amplitude.

    Parameters
    ----------
    n_samples : int
        Samples in one period ``N``.
    n_channels : int
        Number of channels ``C`` (= number of experiments).
    bins : array_like of int
        Excited bins in ``1..N//2``.  The Nyquist bin needs a real orthogonal ``T`` with
        entries ``+-1`` there (a Hadamard matrix), available here when ``C`` is a power of
        two; otherwise it is refused.
    rms : float or array_like, shape (C,)
        Exact rms of each channel (the same in every experiment).
    rng : numpy.random.Generator
        Source of the random phases.

    Returns
    -------
    ndarray of float, shape (C, N, C)
        ``[experiment, time, channel]``; channel ``c`` has the same rms in every experiment.

    Examples
    --------
    >>> u = orthogonal_random_phase_multisines(32, 2, np.arange(1, 9), 1.0,
    ...                                        np.random.default_rng(1))
    >>> U = np.fft.fft(u, axis=1)[:, 3, :]          # U[e, c] at bin 3
    >>> bool(np.allclose(U.conj().T @ U, np.trace(U.conj().T @ U).real / 2 * np.eye(2)))
    True
    """
    n_channels = _check_channels(n_channels)
    bins = check_bins(n_samples, bins)
    check_rng(rng)
    c = np.arange(n_channels)
    # (c * e) mod C keeps the angles exact for larger C.
    t = np.exp(-2j * np.pi * ((c[:, None] * c[None, :]) % n_channels) / n_channels)
    d = np.exp(2j * np.pi * rng.random((bins.size, n_channels)))  # [k, c]
    u = t[None, :, :] * d[:, None, :]  # [k, e, c] = T[e, c] D_c(k)
    if n_samples % 2 == 0 and bins[-1] == n_samples // 2:
        h = _hadamard(n_channels)
        if h is None:
            raise ValueError(
                f"the Nyquist bin {n_samples // 2} must carry a real coefficient, and a real "
                f"orthogonal +-1 matrix of order {n_channels} is not available (only powers of "
                f"two are). Drop bin {n_samples // 2} from bins."
            )
        signs = rng.choice([-1.0, 1.0], size=n_channels)
        u[-1] = h * signs[None, :]  # random signs per channel keep H orthogonal
    phasors = np.moveaxis(u, 1, 0)  # [e, k, c]
    return multisine_from_phasors(n_samples, bins, phasors, rms)


def crest_factor(x, axis) -> np.ndarray:
    """Crest factor ``max|x| / rms(x)`` along ``axis`` (dimensionless, 1 for a square wave).

    Parameters
    ----------
    x : array_like of float
        Signal (one or more periods).
    axis : int
        The time axis.

    Returns
    -------
    ndarray
        ``x`` reduced over ``axis``; ``nan`` where the signal is identically zero.

    Examples
    --------
    >>> crest_factor(np.array([1.0, -1.0, 1.0, -1.0]), axis=0)
    array(1.)
    >>> float(np.round(crest_factor(np.sin(2 * np.pi * np.arange(64) / 64), axis=0), 6))
    1.414214
    """
    x = np.asarray(x, dtype=float)
    peak = np.max(np.abs(x), axis=axis)
    rms = np.sqrt(np.mean(x**2, axis=axis))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(rms > 0, peak / np.where(rms > 0, rms, 1.0), np.nan)
