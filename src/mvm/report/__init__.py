"""See a reconstruction: overlays of every frame, a self-contained HTML report with an
interactive 3D view, and a summary page over many scenes.

- :func:`write_report` -> ``SCENE/mvm/report.html``
- :func:`write_overlays` -> frames as images or an MP4
- :func:`write_summary` -> one page linking every scene's report
"""
from __future__ import annotations

from mvm.report.overlay import write_overlays
from mvm.report.page import write_report
from mvm.report.summary import write_summary

__all__ = ["write_overlays", "write_report", "write_summary"]
