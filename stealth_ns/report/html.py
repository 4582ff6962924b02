"""``report.html``: the Jinja template filled from a report document."""

from __future__ import annotations

from typing import Any

from stealth_ns.foundation.html_page import render_page


def fmt(value: Any, digits: int = 2) -> str:
    """A table cell or inline number: ``–`` for a missing value, yes/no, floats to ``digits``."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def render_html(report: dict[str, Any]) -> str:
    """``report.html``: ``templates/report.html.j2`` filled from the report (autoescaped; inline CSS,
    images referenced relative to the report folder)."""
    filters = {
        "fmt": fmt,
        "fmt_angle": lambda angle: f"{angle:g}",
        "threshold_row": lambda item: [*item[0].split("/"), item[1]],
    }
    return render_page("stealth_ns.report", "report.html.j2", filters, r=report)
