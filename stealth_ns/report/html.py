"""``report.html``: the Jinja template filled from a report document."""

from __future__ import annotations

from typing import Any


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
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("stealth_ns.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["fmt"] = fmt
    env.filters["fmt_angle"] = lambda angle: f"{angle:g}"
    env.filters["threshold_row"] = lambda item: [*item[0].split("/"), item[1]]
    return env.get_template("report.html.j2").render(r=report)
