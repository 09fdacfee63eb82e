"""Plots of an identified FRF dataset: Bode plot, lifted estimates, residual noise.

Every plot function returns a small result object (``figure``, ``axes``, ``lines``)
and takes ``ax=`` to draw into existing axes, so several estimates can be overlaid.
pyplot is imported only when a figure is created, so importing this module never
chooses a matplotlib backend.
"""

from __future__ import annotations

from numbers import Real
from pathlib import Path

from lcmr_xr.io._atomic import atomic_write

from lcmr_xr.plot.bode import BodePlot, bode
from lcmr_xr.plot.lifted import LiftedPlot, NoisePlot, lifted, noise

__all__ = ["BodePlot", "LiftedPlot", "NoisePlot", "bode", "lifted", "noise", "save_figure"]


def save_figure(result_or_fig, path, *, dpi=150):
    """Write a figure to a PNG file atomically.

    The image is written to a temporary file in the destination directory and moved
    over ``path`` with :func:`os.replace`, so readers never see a half-written file and
    a failure leaves neither a partial file nor the temporary one behind.

    Parameters
    ----------
    result_or_fig : BodePlot, LiftedPlot, NoisePlot or matplotlib.figure.Figure
        A plot result (its ``figure`` is saved) or a figure.
    path : str or os.PathLike
        Destination file; must end in ``.png`` and its directory must exist.
    dpi : float, optional
        Resolution in dots per inch (default 150).

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    TypeError
        If ``result_or_fig`` holds no matplotlib Figure.
    ValueError
        If ``path`` does not end in ``.png`` or ``dpi`` is not positive.
    FileNotFoundError
        If the destination directory does not exist.

    Examples
    --------
    >>> import os, tempfile
    >>> import matplotlib.pyplot as plt
    >>> import lcmr_xr.plot
    >>> fig, ax = plt.subplots()
    >>> _ = ax.plot([1, 2, 3])
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = lcmr_xr.plot.save_figure(fig, os.path.join(tmp, "line.png"))
    ...     out.read_bytes()[:8] == b"\\x89PNG\\r\\n\\x1a\\n"
    True
    >>> plt.close(fig)
    """
    from matplotlib.figure import Figure

    figure = getattr(result_or_fig, "figure", result_or_fig)
    if not isinstance(figure, Figure):
        raise TypeError(
            f"save_figure needs a plot result (with .figure) or a matplotlib Figure, got "
            f"{type(result_or_fig).__name__}."
        )
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(
            f"save_figure writes PNG; give a path ending in '.png', got {str(path)!r}."
        )
    if isinstance(dpi, bool) or not isinstance(dpi, Real) or not dpi > 0:
        raise ValueError(f"dpi must be a positive number (dots per inch, e.g. 150), got {dpi!r}.")
    return atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=dpi))
