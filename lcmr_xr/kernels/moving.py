"""Moving sums over bins whose values span many decades, on plain arrays (no labels).

Spectra, noise variances and squared FRF errors span tens of decades across frequency,
so a running sum over all bins (one cumulative sum, each window the difference of two
of its values) would leave every window with the rounding of all the bins before it:
the small values far from the large ones are lost.  Here the bins are cut into blocks
of one window, and each window is the suffix sum of one block plus the prefix sum of the
next: both only add bins of that window (rounding relative to the window's own
magnitude, at most ``w + 1`` roundings of its terms), and the cost does not grow with the
window.  Used by :func:`lcmr_xr.kernels.pooling.window_mean` (circular windows) and the
smoothing of :mod:`lcmr_xr.kernels.adaptive` (windows cut at the ends).
"""

from __future__ import annotations

import numpy as np

__all__ = ["window_sums"]


def window_sums(x: np.ndarray, width: int, *, pad: int = 0) -> np.ndarray:
    """Sums over every run of ``width`` consecutive entries along the first axis.

    Entry ``s`` of the result is ``x[s] + ... + x[s + width - 1]`` (of ``x`` with ``pad``
    zeros before and after it), each summed from that window's terms only (module notes),
    in ``O(1)`` per window.

    Parameters
    ----------
    x : ndarray, shape (L, ...)
        Values per bin along the first axis, any trailing axes.
    width : int
        ``w >= 1``, bins per window.
    pad : int, default 0
        Zeros taken before and after ``x`` (windows cut at the ends, when ``pad`` is
        ``(w - 1) / 2``: one sum centred on every bin).

    Returns
    -------
    ndarray, shape (max(L + 2 pad - w + 1, 0), ...)
        Floating point (``x``'s type promoted to at least float64's kind).

    Examples
    --------
    >>> window_sums(np.array([1e20, 1.0, 2.0, 3.0]), 2).tolist()
    [1e+20, 3.0, 5.0]
    >>> window_sums(np.array([1.0, 2.0, 3.0]), 3, pad=1).tolist()
    [3.0, 6.0, 5.0]
    """
    x = np.asarray(x)
    w, pad = int(width), int(pad)
    rest = x.shape[1:]
    length = x.shape[0] + 2 * pad
    n_blocks = -(-length // w) + 1  # one spare block: the last window may read a prefix of it
    flat = np.zeros((n_blocks * w,) + rest, dtype=np.result_type(x.dtype, float))
    flat[pad:pad + x.shape[0]] = x
    blocks = flat.reshape((n_blocks, w) + rest)
    # prefix[b w + o] = block b's first o + 1 terms; suffix[b w + o] = its terms o..w-1
    # (the blocks' cumulative sums read backwards: a view, no copy)
    prefix = np.cumsum(blocks, axis=1).reshape(flat.shape)
    suffix = np.cumsum(blocks[::-1, ::-1], axis=1).reshape(flat.shape)[::-1]
    n_sums = max(length - w + 1, 0)
    # window s = b w + o: block b from o on, plus block b + 1's first o (none when o = 0)
    sums = suffix[:n_sums] + prefix[w - 1:w - 1 + n_sums]
    sums[::w] = suffix[:n_sums:w]
    return sums
