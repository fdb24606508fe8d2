"""An analysis displays itself in Jupyter: the verdict, the parameters and what pins them down, the selection,
the warnings and the key figures (slices, residuals and, for a simulated run, the truth), inline.

:class:`analysis.result.Analysis` sits below the page's pieces, so its ``_repr_html_`` calls the renderer this
module registers; analysis.analyze (where an analysis is made) imports it. The figures are drawn into a
temporary directory and embedded as base64 PNG, so a saved notebook keeps them.
"""

from __future__ import annotations

import base64
import tempfile
from html import escape
from pathlib import Path

from analysis.result import HTML_REPR, Analysis

#: The figures a notebook display shows (the page has them all).
KEY_FIGURES = ("slices", "residuals", "truth")


def analysis_html(a: Analysis) -> str:
    """The notebook display of an analysis (an HTML fragment with inline figures)."""
    from analysis.report.html import CSS, _parameters, _selection, page_warnings
    from analysis.report.plots import write_figures

    with tempfile.TemporaryDirectory(prefix="gonio-repr-") as d:
        figs = write_figures(a, Path(d), names=KEY_FIGURES)
        imgs = "".join(
            f'<figure><img src="data:image/png;base64,{base64.b64encode(f.png.read_bytes()).decode("ascii")}" '
            f'style="max-width:100%"><figcaption>{escape(f.caption)}</figcaption></figure>'
            for f in figs.files
        )
    warns = "".join(f"<li>{escape(w)}</li>" for w in page_warnings(a))
    return (f'<div class="gonio"><style>{CSS.replace("body {", ".gonio {")}</style>'
            f'<p class="verdict">{escape(a.verdict())}</p>{_parameters(a.selection.chosen, a)}'
            f"<h4>Model selection</h4>{_selection(a)}" + (f"<h4>Warnings</h4><ul>{warns}</ul>" if warns else "")
            + imgs + "</div>")  # fmt: skip


if not HTML_REPR:
    HTML_REPR.append(analysis_html)
