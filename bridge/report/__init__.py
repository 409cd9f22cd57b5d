"""The mission report: time series gathered from a run's events, drawn into one HTML file."""

from typing import Any

from bridge.report.recorder import MissionRecorder, Recording

__all__ = ["MissionRecorder", "Recording", "write_report"]


def __getattr__(name: str) -> Any:
    """``write_report`` on first use: plotly is imported when a page is drawn, not by every
    run that reads ``bridge.report.model`` or ``bridge.report.age``."""
    if name == "write_report":
        from bridge.report.html import write_report

        return write_report
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
