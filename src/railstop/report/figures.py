"""What every plot of railstop shares: writing a figure file with a clear error."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from railstop.errors import RailstopError

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def write_figure(fig: Figure, path: Path, dpi: int) -> Path:
    """Save ``fig`` to ``path``; an unwritable path is a RailstopError naming it."""
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise RailstopError(f"{path}: cannot write the plot: {exc.strerror or exc}") from None
    except ValueError as exc:  # matplotlib: a file name whose extension is no image format
        raise RailstopError(f"{path}: cannot write the plot: {exc}".splitlines()[0].rstrip(",")) from None
    return path
