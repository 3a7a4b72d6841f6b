"""Reports of simulated stops: plots of the single detailed stop."""

from __future__ import annotations

from railstop.report.plot import PSD_TOLERANCE_M, plot_stop

__all__ = ["PSD_TOLERANCE_M", "plot_stop"]
