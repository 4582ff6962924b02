"""HTML pages from the package's Jinja templates (report.html, scan.html): one environment's settings."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def render_page(
    package: str, template: str, filters: dict[str, Callable[..., Any]] | None = None, **context: Any
) -> str:
    """``package``'s ``templates/TEMPLATE`` filled with ``context``: autoescaped, undefined names an
    error (a template that reads a missing key fails loudly), block whitespace trimmed."""
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader(package, "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters.update(filters or {})
    return env.get_template(template).render(**context)
