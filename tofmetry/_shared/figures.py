"""Figures without pyplot's global state, and the one figure -> PNG saver (atomic).

:func:`subplots` is :func:`matplotlib.pyplot.subplots` without pyplot: the figure belongs to no
backend or window manager, so making tofmetry's figures never switches the backend of the
caller's session (a notebook keeps its inline plots) and nothing has to be closed.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from tofmetry._shared.atomic import atomic_write_bytes


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float] | None = None, **kwargs):
    """A new figure and its axes, as ``matplotlib.pyplot.subplots`` returns them.

    Parameters
    ----------
    nrows, ncols : grid of axes
    figsize : (width, height) [inch]
    **kwargs : passed to :meth:`matplotlib.figure.Figure.subplots` (``squeeze``, ``gridspec_kw``...)

    Returns
    -------
    fig : Figure; axes : one Axes or an array of them
    """
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def figure_png_bytes(fig: Figure, dpi: int = 110, tight: bool = False) -> bytes:
    """Render ``fig`` to PNG bytes (and close it if pyplot holds it).

    Parameters
    ----------
    fig : matplotlib Figure
    dpi : resolution [dots per inch]
    tight : crop to the drawn content (``bbox_inches="tight"``)
    """
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, **({"bbox_inches": "tight"} if tight else {}))
    finally:
        plt.close(fig)  # a figure made with pyplot elsewhere; a no-op for one made by subplots()
    return buf.getvalue()


def save_png(fig: Figure, path: str | os.PathLike, dpi: int = 110, tight: bool = False) -> Path:
    """Write ``fig`` as a PNG file atomically; returns the path.

    Parameters
    ----------
    fig : matplotlib Figure
    path : the PNG file (its folder is created if needed)
    dpi, tight : as :func:`figure_png_bytes`
    """
    return atomic_write_bytes(path, figure_png_bytes(fig, dpi=dpi, tight=tight))
