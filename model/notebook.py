"""Pieces of the rich displays in Jupyter (``_repr_html_``) of fits, plans and analyses, shared by every layer.

A figure goes inline as a base64 PNG, so a notebook saved to disk keeps it without any file beside it.
matplotlib is imported only when a display is drawn, never by importing the models.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Sequence
from html import escape
from typing import Any


def figure_img(fig: Any, dpi: int = 80) -> str:
    """An <img> tag holding the matplotlib Figure ``fig`` as an inline PNG."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


def html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A small HTML table of plain-text cells (each escaped here)."""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
