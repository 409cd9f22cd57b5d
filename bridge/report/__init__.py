"""The mission report: time series gathered from a run's events, drawn into one HTML file."""

from bridge.report.html import write_report
from bridge.report.recorder import MissionRecorder, Recording

__all__ = ["MissionRecorder", "Recording", "write_report"]
