"""Reports of simulated stops: plots of the single detailed stop."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from railstop.report.plot import plot_stop

__all__ = ["plot_stop"]


def __getattr__(name: str) -> Any:
    # On first use: the plot module imports matplotlib, and the campaign code imports this package
    # (railstop.report.campaign_report) without drawing anything.
    if name in __all__:
        from railstop.report import plot

        return getattr(plot, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
