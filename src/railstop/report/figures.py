"""What every plot of railstop shares: writing a figure file with a clear error."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from railstop.errors import RailstopError

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def figure_path(path: str | Path) -> Path:
    """The file a plot is written to: ``path``, with ``.png`` added when it has no extension; a
    folder is a RailstopError (a plot needs a file name)."""
    out = Path(path)
    if out.is_dir():
        raise RailstopError(f"{out}: is a folder; give the plot a file name, e.g. {out / 'plot.png'}")
    return out if out.suffix else out.with_name(out.name + ".png")


def write_figure(fig: Figure, path: Path, dpi: int) -> Path:
    """Save ``fig`` to :func:`figure_path` of ``path`` and return that file; an unwritable path
    is a RailstopError naming it."""
    path = figure_path(path)
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise RailstopError(f"{path}: cannot write the plot: {exc.strerror or exc}") from None
    except ValueError as exc:  # matplotlib: a file name whose extension is no image format
        raise RailstopError(f"{path}: cannot write the plot: {exc}".splitlines()[0].rstrip(",")) from None
    return path
