"""In a notebook a fit, a plan and an analysis display themselves: ``_repr_html_`` with their key figures inline."""

from __future__ import annotations

import base64
import re

from analysis.analyze import load_and_fit  # noqa: F401  (importing analysis.analyze registers the analysis display)
from model.fit.solve import fit
from model.fit.spec import ggx_conductor
from rig.run.session import make_plan
from tests.analysis.test_report_honesty import GOLD, analysis_of, in_plane
from tests.run_helpers import in_plane_sweep, sim_rig

PNG = b"\x89PNG\r\n\x1a\n"


def inline_pngs(html: str) -> list[bytes]:
    """The PNG images embedded in ``html`` as data URIs, decoded."""
    return [base64.b64decode(m) for m in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html)]


def test_a_fit_shows_its_parameters_and_a_residual_histogram() -> None:
    s = in_plane(GOLD)
    r = fit(ggx_conductor(), s, starts=1, warn=False)
    html = r._repr_html_()
    assert "ggx_conductor" in html and "<td>alpha</td>" in html and "chi2/dof" in html
    pngs = inline_pngs(html)
    assert len(pngs) == 1 and pngs[0][:8] == PNG


def test_an_analysis_shows_the_verdict_the_parameters_and_the_key_figures() -> None:
    a = analysis_of(in_plane(GOLD), [ggx_conductor()], truth=GOLD)
    html = a._repr_html_()
    assert a.verdict().split(",")[0] in html and "not pinned down by the data" in html
    assert "Model selection" in html and '<table class="corr">' in html
    pngs = inline_pngs(html)
    assert len(pngs) == 3 and all(p[:8] == PNG for p in pngs)  # slices, residuals, truth
    assert "<script" not in html.lower()


def test_a_plan_shows_its_summary_and_its_directions() -> None:
    rig = sim_rig()
    plan = make_plan(rig, in_plane_sweep([20.0, 85.0], [-60.0, 0.0, 60.0]))
    html = plan._repr_html_()
    assert "Estimated run time" in html and plan.summary().splitlines()[0] in html
    assert len(inline_pngs(html)) == 1
