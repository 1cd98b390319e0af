"""report.html (petsoft.diagnosis.html): made from report.md, figures embedded, rendered by a real
browser (Debian's chromium, headless; scripts/bootstrap.sh installs it)."""

from __future__ import annotations

import html
import os
import re
import shutil
import subprocess

import pytest
from test_diagnosis_analysis import example_report
from test_figures import _record

from petsoft.diagnosis import report
from petsoft.diagnosis.figures import CAPTIONS, plot_candidates, plot_displacement
from petsoft.diagnosis.html import markdown_to_html, write_report_html
from petsoft.diagnosis.story import quoted_conflicts

pytestmark = pytest.mark.serial_only      # one browser is enough


def _report_dir(tmp_path):
    t, ref, data, before, after = _record()
    plot_displacement(tmp_path / "displacement.png", t, data, before, after, ref, cut=0.7)
    plot_candidates(tmp_path / "candidates.png", [{"physics": "damping.mass", "score": 900.0},
                                                  {"physics": "drag.linear", "score": 3.0}],
                    added=["damping.mass"])
    figures = ["displacement.png", "candidates.png"]
    md = report.write_report_md(tmp_path / "report.md", example_report(), {}, figures)
    # as the diagnosis passes them: paths as the caller has them (relative to the working dir)
    return write_report_html(tmp_path / "report.html", md,
                             [os.path.relpath(tmp_path / f) for f in figures])


def test_markdown_subset_becomes_html():
    body, images = markdown_to_html(
        "# Title\n\n**Verdict: missing physics.** The <residual> is `big`.\n\n"
        "| a | b |\n|---|---|\n| 1 | 2 |\n\n- one\n- **two**\n\n![fig](x.png)\n")
    assert "<h1>Title</h1>" in body and '<p class="verdict">' in body
    for words, cls in (("consistent.", "verdict consistent"),
                       ("numerics, no missing physics.", "verdict numerics")):
        assert f'<p class="{cls}">' in markdown_to_html(f"**Verdict: {words}** x")[0]
    assert "&lt;residual&gt;" in body and "<code>big</code>" in body       # escaped, inline code
    assert "<th>a</th>" in body and "<td>2</td>" in body and "---" not in body
    assert "<li><strong>two</strong></li>" in body and images == ["x.png"]


def test_page_is_self_contained_with_the_verdict_first_and_figures_in_their_sections(tmp_path):
    page = _report_dir(tmp_path).read_text()
    assert "http" not in page.replace("http-equiv", "")          # nothing fetched
    assert "<script" not in page
    body = page[page.index("<body>"):]
    assert body.index("Verdict: missing physics") < body.index("Where and when")
    imgs = re.findall(r'<img alt="([^"]+)" src="data:image/png;base64,', page)
    assert imgs == [html.escape(CAPTIONS["displacement"]), html.escape(CAPTIONS["candidates"])]
    # the displacement under "Where and when", the candidates under "Physics", both before the
    # folded appendix
    shown = body.index("<img")
    assert body.index("Where and when") < shown < body.index("Physics")
    assert body.index("Physics") < body.rindex("<img") < body.index("<details>")
    assert "<details><summary>Appendix" in body and "<details open" not in body
    assert body.index("<details>") < body.index("<h3>Fit</h3>") < body.index("</details>")
    assert quoted_conflicts(page) == []


@pytest.mark.skipif(shutil.which("chromium") is None,
                    reason="chromium is not installed (scripts/bootstrap.sh installs it)")
def test_a_real_browser_renders_the_page(tmp_path):
    page = _report_dir(tmp_path)
    shot = tmp_path / "shot.png"
    common = ["chromium", "--headless", "--no-sandbox", "--disable-gpu",
              f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1200,2400"]
    subprocess.run(common + [f"--screenshot={shot}", page.as_uri()], check=True,
                   capture_output=True, timeout=120)
    dom = subprocess.run(common + ["--dump-dom", page.as_uri()], check=True,
                         capture_output=True, text=True, timeout=120).stdout
    assert "Verdict: missing physics" in dom
    assert dom.count("data:image/png;base64,") == 2
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[0] >= 2000 and pixels.shape[1] >= 1100
    grey = pixels[..., :3].mean(axis=2)
    # not blank: text and figures make dark pixels in the top and in the lower part
    assert (grey < 0.3).mean() > 0.002
    assert (grey[1200:] < 0.5).mean() > 0.001
