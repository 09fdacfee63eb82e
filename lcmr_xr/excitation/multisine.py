"""Labelled periodic multisine excitations (time x channel DataArrays) for experiments.

Thin layer over :mod:`lcmr_xr.kernels.excitation`: it turns a frequency band in hertz
into DFT bins, labels the channels, repeats the period, and records in attributes every
setting needed to regenerate the signal (seed, bins, phases).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from lcmr_xr.conventions import CHANNEL, EXPERIMENT, TIME, label_attrs, time_attrs
from lcmr_xr.kernels import excitation as kernels
from lcmr_xr.settings import as_integer

__all__ = ["bins_for_band", "multisine", "orthogonal_multisines"]

_PHASES = ("random", "schroeder")


def bins_for_band(n_samples: int, sampling_period: float, band) -> np.ndarray:
    """DFT bins ``k`` in ``1..N//2`` whose frequency ``k / (N Ts)`` lies in ``band`` (Hz).

    Parameters
    ----------
    n_samples : int
        Samples in one period ``N``.
    sampling_period : float
        ``Ts`` in s.
    band : tuple of float
        ``(f_lo, f_hi)`` in Hz, both ends included.

    Returns
    -------
    ndarray of int64
        The selected bins, ascending.

    Examples
    --------
    >>> bins_for_band(100, 0.01, (2.0, 5.0)).tolist()
    [2, 3, 4, 5]
    """
    lo, hi = (float(b) for b in band)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"band must be (f_lo, f_hi) in Hz with f_lo <= f_hi, got {band!r}.")
    k = np.arange(1, int(n_samples) // 2 + 1)
    f = k / (int(n_samples) * float(sampling_period))
    # A tiny relative slack so that band edges typed as k/(N Ts) are included.
    tol = 1e-9 * max(abs(hi), 1.0 / (n_samples * sampling_period))
    sel = k[(f >= lo - tol) & (f <= hi + tol)]
    if sel.size == 0:
        df = 1.0 / (n_samples * sampling_period)
        raise ValueError(
            f"band {band!r} Hz contains no DFT bin: bins are spaced by {df:g} Hz from {df:g} up "
            f"to the Nyquist frequency {k[-1] * df:g} Hz. Widen the band or lengthen the period."
        )
    return sel


def _channel_labels(channels, n_rms: int | None) -> list[str]:
    if channels is None:
        n = 1 if n_rms is None else n_rms
        return [f"u{i}" for i in range(n)]
    if isinstance(channels, (int, np.integer)) and not isinstance(channels, bool):
        if channels < 1:
            raise ValueError(f"channels must be at least 1, got {channels}.")
        return [f"u{i}" for i in range(int(channels))]
    if isinstance(channels, str) or not isinstance(channels, Sequence):
        raise TypeError(
            f"channels must be a count or a sequence of labels, got {channels!r}; "
            "e.g. channels=2 or channels=['u0', 'u1']."
        )
    labels = [str(c) for c in channels]
    if len(set(labels)) != len(labels) or not labels:
        raise ValueError(f"channel labels must be unique and non-empty, got {labels}.")
    return labels


def _prepare(n_samples, sampling_period, rms, channels, band, bins, periods, seed):
    # whole numbers only: 1000.5 samples or 2.5 periods are refused, never truncated
    n_samples = as_integer(n_samples, "n_samples", minimum=2, example=1000)
    ts = float(sampling_period)
    if not np.isfinite(ts) or ts <= 0:
        raise ValueError(f"sampling_period must be a positive time in s, got {sampling_period!r}.")
    periods = as_integer(periods, "periods", minimum=1, example=1)
    rms_arr = np.asarray(rms, dtype=float)
    labels = _channel_labels(channels, rms_arr.size if rms_arr.ndim == 1 else None)
    if band is not None and bins is not None:
        raise ValueError("pass either band=(f_lo, f_hi) or bins=[...], not both.")
    if band is not None:
        k = bins_for_band(n_samples, ts, band)
    elif bins is not None:
        k = kernels.check_bins(n_samples, bins)
    else:
        k = np.arange(1, n_samples // 2 + 1)
    k = kernels.check_bins(n_samples, k)
    if seed is None:
        # Draw a seed and record it, so even an unseeded signal can be regenerated.
        seed = int(np.random.SeedSequence().generate_state(1, np.uint32)[0])
    if isinstance(seed, (bool, np.bool_)) or int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}.")
    return n_samples, ts, rms_arr, labels, k, int(periods), int(seed)


def _label(x, n_samples, ts, labels, k, periods, dim, units, extra_dims=()):
    """Wrap one period ``(..., N, C)`` into a DataArray with repeated periods and coords."""
    reps = (1,) * (x.ndim - 2) + (periods, 1)
    data = np.tile(x, reps)
    n_total = n_samples * periods
    cf = kernels.crest_factor(x, axis=-2)
    dims = tuple(extra_dims) + (TIME, dim)
    coords = {
        TIME: (TIME, np.arange(n_total) * ts, time_attrs()),
        dim: (dim, np.array(labels), label_attrs("channel")),
        "crest_factor": (
            tuple(extra_dims) + (dim,),
            cf,
            {"units": "1", "long_name": "crest factor (peak / rms over one period)"},
        ),
    }
    df = 1.0 / (n_samples * ts)
    attrs = {
        "units": units,
        "long_name": "multisine excitation",
        "n_samples_per_period": n_samples,
        "periods": periods,
        "sampling_period": ts,
        "excited_bins": k.astype(np.int64),
        "band": np.array([k[0] * df, k[-1] * df]),
        "band_units": "Hz",
    }
    return xr.DataArray(data, dims=dims, coords=coords, attrs=attrs)


def multisine(
    n_samples: int,
    *,
    sampling_period: float,
    rms,
    channels=None,
    band=None,
    bins=None,
    periods: int = 1,
    seed: int | None = None,
    phases: str = "random",
    dim: str = CHANNEL,
    units: str = "1",
) -> xr.DataArray:
    """Periodic multisine excitation with a flat amplitude spectrum on the excited bins.

    Parameters
    ----------
    n_samples : int
        Samples in ONE period ``N`` (the signal has ``N * periods`` samples).
    sampling_period : float
        Sample time ``Ts`` in s; bin ``k`` is at ``k / (N Ts)`` Hz.
    rms : float or array_like
        Exact rms per channel (in ``units``), a scalar or one value per channel.
    channels : int or sequence of str, optional
        Number of channels (labels ``"u0", "u1", ...``) or the labels.  Default: one channel,
        or one per ``rms`` value.
    band : tuple of float, optional
        ``(f_lo, f_hi)`` in Hz: excite every bin in this band (ends included).
    bins : array_like of int, optional
        Excite exactly these bins (``1..N//2``).  Default (neither ``band`` nor ``bins``): all
        bins ``1..N//2``.  DC is never excited; the Nyquist bin is real with random sign.
    periods : int, default 1
        Number of repeated periods (extra periods let transients die out).
    seed : int, optional
        Seed of the random phases; the same seed gives the same signal.  Default: a fresh
        seed, recorded in ``attrs["seed"]``.
    phases : {"random", "schroeder"}, default "random"
        Independent uniform random phases per channel, or deterministic Schroeder phases
        (low crest factor, the same on every channel, ``seed`` unused).
    dim : str, default "channel"
        Name of the channel dimension (e.g. ``"input"``).
    units : str, default "1"
        Unit of the signal.

    Returns
    -------
    xarray.DataArray
        Dims (``time``, ``dim``); ``time`` starts at 0 s spaced by ``Ts``; coordinate
        ``crest_factor`` on ``dim``; attrs ``band`` (Hz, lowest and highest excited bin),
        ``excited_bins``, ``seed``, ``phases``, ``periods``, ``n_samples_per_period``.

    Examples
    --------
    >>> u = multisine(100, sampling_period=1e-3, rms=[1.0, 2.0], band=(10, 200), seed=1)
    >>> u.dims, u.sizes["time"], np.round(np.sqrt((u**2).mean("time")).values, 12).tolist()
    (('time', 'channel'), 100, [1.0, 2.0])
    """
    if phases not in _PHASES:
        raise ValueError(f"phases must be one of {_PHASES}, got {phases!r}.")
    n, ts, rms_arr, labels, k, periods, seed = _prepare(
        n_samples, sampling_period, rms, channels, band, bins, periods, seed
    )
    if phases == "random":
        x = kernels.random_phase_multisine(n, len(labels), k, rms_arr, np.random.default_rng(seed))
    else:
        x = kernels.schroeder_multisine(n, len(labels), k, rms_arr)
    out = _label(x, n, ts, labels, k, periods, dim, units)
    out.attrs.update(phases=phases)
    if phases == "random":
        out.attrs["seed"] = seed
    return out


def orthogonal_multisines(
    n_samples: int,
    *,
    sampling_period: float,
    rms,
    channels=None,
    band=None,
    bins=None,
    periods: int = 1,
    seed: int | None = None,
    dim: str = CHANNEL,
    units: str = "1",
) -> xr.DataArray:
    """Orthogonal random-phase multisines: one experiment per channel, for MIMO designs.

    At each excited bin the ``experiment x channel`` matrix of spectra is ``T D(k)``, with
    ``T`` the DFT matrix and ``D(k)`` random phases per channel, so it is orthogonal at
    every bin (Dobrowiecki, Schoukens and Guillaume, 2006); see
    :func:`lcmr_xr.kernels.excitation.orthogonal_random_phase_multisines`.

    Parameters
    ----------
    n_samples : int
        Samples in ONE period ``N`` (the signal has ``N * periods`` samples).
    sampling_period : float
        Sample time ``Ts`` in s.
    rms : float or array_like
        Exact rms per channel, the same in every experiment.
    channels : int or sequence of str, optional
        Channel count or labels (default one per ``rms`` value, else one); also the number
        of experiments.
    band : tuple of float, optional
        ``(f_lo, f_hi)`` in Hz, as in :func:`multisine`.
    bins : array_like of int, optional
        Explicit bins, as in :func:`multisine` (default all ``1..N//2``).  With more than
        one channel the Nyquist bin can be excited only when the channel count is a power
        of two.
    periods : int, default 1
        Number of repeated periods.
    seed : int, optional
        Seed of the random phases (default: fresh, recorded in ``attrs["seed"]``).
    dim : str, default "channel"
        Name of the channel dimension.
    units : str, default "1"
        Unit of the signal.

    Returns
    -------
    xarray.DataArray
        Dims (``experiment``, ``time``, ``dim``), ``experiment`` labelled ``0..C-1``;
        coordinate ``crest_factor`` on (``experiment``, ``dim``).

    Examples
    --------
    >>> u = orthogonal_multisines(64, sampling_period=0.01, rms=1.0, channels=2,
    ...                           band=(1, 20), seed=3)
    >>> u.dims, u.sizes["experiment"]
    (('experiment', 'time', 'channel'), 2)
    """
    n, ts, rms_arr, labels, k, periods, seed = _prepare(
        n_samples, sampling_period, rms, channels, band, bins, periods, seed
    )
    x = kernels.orthogonal_random_phase_multisines(
        n, len(labels), k, rms_arr, np.random.default_rng(seed)
    )
    out = _label(x, n, ts, labels, k, periods, dim, units, extra_dims=(EXPERIMENT,))
    out = out.assign_coords(
        {EXPERIMENT: (EXPERIMENT, np.arange(len(labels)), label_attrs("experiment"))}
    )
    out.attrs.update(phases="orthogonal random", seed=seed)
    return out
