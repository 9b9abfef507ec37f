"""MkDocs hooks of the docs site (``mkdocs.yml``'s ``hooks``).

The docstrings name code with Sphinx roles (``:func:`way_back```, ``:class:`~onlinemap.belief.Belief```),
which the markdown docstrings render as the role's name followed by code. :func:`on_page_content`
drops the role and keeps the code, shortened to its last component after a ``~`` as Sphinx does.
"""

from __future__ import annotations

import re

ROLE = re.compile(r":(?:func|class|mod|data|meth|attr|exc|obj|const):<code>(~?)([^<]*)</code>")


def _code(match: re.Match) -> str:
    tilde, name = match.groups()
    return f"<code>{name.rsplit('.', 1)[-1] if tilde else name}</code>"


def on_page_content(html: str, **_) -> str:
    """The page's HTML with every Sphinx role before inline code removed. O(len(html))."""
    return ROLE.sub(_code, html)
