"""MkDocs hook: the docstrings' Sphinx roles (``:func:`name```) shown as plain code.

The package's docstrings are numpydoc with Sphinx cross-reference roles, for ``help()`` and
IDEs; Markdown renders ``:func:`x``` as the text ``:func:`` followed by ``x`` in code. The
role's name is dropped here, after rendering, leaving the code.
"""

from __future__ import annotations

import re
from typing import Any

_ROLE = re.compile(r":(?:func|meth|class|mod|data|attr|obj|exc|const|py:\w+):(?=<code>)")


def on_page_content(html: str, **kwargs: Any) -> str:
    return _ROLE.sub("", html)
