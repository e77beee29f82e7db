"""Autoescaping for the HTML pages (``reports.html``, ``captures.diff_html``): fragments are
``string.Template`` s filled by :func:`fill`, which escapes each value (``html.escape``,
quotes too) unless it is :class:`Markup`, HTML built by a template or a chart of
``reports.chart`` (which escapes its own text). Escaping is the default, as in a template
engine with autoescape; ``string.Template`` rather than jinja2, which is not among the
project's dependencies: the pages are a few fixed fragments, and :func:`fill` is the one
place where values meet markup."""

from __future__ import annotations

from collections.abc import Iterable
from html import escape
from string import Template
from typing import Any

__all__ = ["Markup", "Template", "attrs", "e", "fill", "join"]


class Markup(str):
    """HTML put into a template as it is. Every other value is escaped."""


def e(text: Any) -> str:
    """``text`` escaped for an element or a quoted attribute (None: nothing)."""
    return escape("" if text is None else str(text), quote=True)


def fill(template: Template, **values: Any) -> Markup:
    """``template`` filled with ``values``, each escaped unless it is :class:`Markup`."""
    return Markup(template.substitute({k: v if isinstance(v, Markup) else e(v) for k, v in values.items()}))


def join(parts: Iterable[Any], sep: str = "") -> Markup:
    """``parts`` one after the other, each escaped unless it is :class:`Markup`."""
    return Markup(sep.join(p if isinstance(p, Markup) else e(p) for p in parts))


_ATTR = Template(' $name="$value"')


def attrs(values: dict[str, Any]) -> Markup:
    """``name="value"`` pairs, each a space ahead, names and values escaped."""
    return join(fill(_ATTR, name=k, value=v) for k, v in values.items())
