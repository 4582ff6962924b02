"""The README's and the docs' relative links lead to files that exist (the site's build checks the links
between its own pages; the README is not one of them, and a page may link to a file outside the site)."""

from __future__ import annotations

import re
from pathlib import Path

from doc_examples import ROOT

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def relative_links(page: Path) -> list[str]:
    """The targets of a page's markdown links that are paths in this repository (no URL, no anchor)."""
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    targets = [m.group(1).split("#")[0] for m in LINK.finditer(text)]
    return [t for t in targets if t and not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def broken_links(pages: list[Path]) -> list[str]:
    return [
        f"{page.relative_to(ROOT)}: {target}"
        for page in pages
        for target in relative_links(page)
        if not (page.parent / target).exists()
    ]


def test_every_relative_link_of_the_readme_and_the_docs_exists():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    pages = [p for p in pages if "_build" not in p.parts]
    found = broken_links(pages)
    assert not found, "broken links:\n" + "\n".join(found)


def test_a_broken_link_is_found(tmp_path: Path, monkeypatch):
    page = tmp_path / "page.md"
    page.write_text(
        "[a](missing.md) [b](https://example.org) [c](#here) ![d](page.md)\n```\n[e](x.md)\n```\n"
    )
    monkeypatch.setattr("test_doc_links.ROOT", tmp_path)
    assert broken_links([page]) == ["page.md: missing.md"]
