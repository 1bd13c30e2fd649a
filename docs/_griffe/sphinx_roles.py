"""A griffe extension for the API reference: Sphinx roles in docstrings become inline code.

The docstrings name other objects with Sphinx roles (:func:`score_clip`,
:class:`~geocon_core.media.reader.ClipError`); Markdown has no roles, so the reference pages would
show the role's name beside the code. ``:role:`~a.b.C``` becomes ```C``` (Sphinx shows the last
part after a tilde), ``:role:`a.b.C``` becomes ```a.b.C```, and ``:role:`title <target>``` becomes
```title```. Loaded by mkdocstrings (``mkdocs.yml``); nothing in the packages imports it.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const|ref|term):`([^`]+)`")


def _plain(match: re.Match[str]) -> str:
    target = match.group(1).strip()
    titled = re.fullmatch(r"(.+?)\s*<[^<>]+>", target)
    if titled:
        target = titled.group(1)
    elif target.startswith("~"):
        target = target[1:].rsplit(".", 1)[-1]
    return f"`{target}`"


def strip_roles(text: str) -> str:
    """``text`` with every Sphinx cross-reference role replaced by inline code."""
    return _ROLE.sub(_plain, text)


class SphinxRoles(griffe.Extension):
    """Rewrite the roles of every docstring once the object tree is complete."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = strip_roles(obj.docstring.value)

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        # The root package's own docstring (on_object covers its members).
        self.on_object(obj=pkg)
