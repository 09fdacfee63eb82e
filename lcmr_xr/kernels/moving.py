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


def window_sums(x: np.ndarray, width: int) -> np.ndarray:
    """Sums over every run of ``width`` consecutive entries along the first axis.

    Entry ``s`` of the result is ``x[s] + ... + x[s + width - 1]``, each summed from
    that window's terms only (module notes), in ``O(1)`` per window.

    Parameters
    ----------
    x : ndarray, shape (L, ...)
        Values per bin along the first axis, any trailing axes.
    width : int
        ``w >= 1``, bins per window.

    Returns
    -------
    ndarray, shape (max(L - w + 1, 0), ...)
        Floating point (``x``'s type promoted to at least float64's kind).

    Examples
    --------
    >>> window_sums(np.array([1e20, 1.0, 2.0, 3.0]), 2).tolist()
    [1e+20, 3.0, 5.0]
    """
    x = np.asarray(x)
    w = int(width)
    length = x.shape[0]
    rest = x.shape[1:]
    n_blocks = -(-length // w) + 1  # one spare block: the last window may read a prefix of it
    blocks = np.zeros((n_blocks * w,) + rest, dtype=np.result_type(x.dtype, float))
    blocks[:length] = x
    blocks = blocks.reshape((n_blocks, w) + rest)
    prefix = np.cumsum(blocks, axis=1)  # prefix[b, o] = sum of the first o + 1 of block b
    suffix = np.cumsum(blocks[:, ::-1], axis=1)[:, ::-1]  # suffix[b, o] = from o to the end
    start = np.arange(max(length - w + 1, 0))
    b, o = start // w, start % w
    return suffix[b, o] + np.where((o > 0).reshape((-1,) + (1,) * len(rest)),
                                   prefix[b + 1, np.maximum(o - 1, 0)], 0.0)
