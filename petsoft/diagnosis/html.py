"""``report.html``: the diagnosis report as one self-contained page (no network, no scripts).

The page is made from ``report.md`` (so the two never say different things): its headings,
paragraphs, lists, tables, **bold** and ``code`` become HTML, and every figure is embedded as a
base64 PNG under the section it belongs to (the displacement, the residual on the body, the
spectra under "Where and when", the candidates under "Physics"), captioned with what to see
(:data:`~petsoft.diagnosis.figures.CAPTIONS`); figures no section claims follow. The appendix,
a ``<details>`` block in report.md, stays folded on the page. Only the subset of Markdown that
:func:`~petsoft.diagnosis.report.write_report_md` writes is understood.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Sequence
from pathlib import Path

from petsoft.atomic import write_text

__all__ = ["FIGURE_SECTIONS", "markdown_to_html", "write_report_html"]

#: Which figures (file stems) go under which section heading of report.md.
FIGURE_SECTIONS = {
    "Where and when": ("displacement", "residual_on_body", "residual_markers", "residual_time",
                       "spectra"),
    "Physics": ("candidates",),
}

_CSS = """
body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em;
       line-height: 1.45; color: #222; }
h1 { border-bottom: 2px solid #444; }
h2 { border-bottom: 1px solid #bbb; margin-top: 1.8em; }
table { border-collapse: collapse; margin: 0.8em 0; }
td, th { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; }
th { background: #eee; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #444; }
details { margin-top: 2em; border-top: 1px solid #bbb; padding-top: 0.5em; }
summary { cursor: pointer; font-weight: bold; }
.verdict { font-size: 1.15em; background: #f4f4f4; padding: 0.8em; border-left: 5px solid #c33; }
.verdict.consistent { border-left-color: #3a3; }
.verdict.numerics { border-left-color: #d90; }
code { background: #f2f2f2; padding: 0 0.2em; }
"""


def _inline(text: str) -> str:
    """Escape, then **bold** and `code`."""
    out = html.escape(text, quote=False)
    out = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", out)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", out)


def _table(rows: list[str]) -> str:
    cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
    head, body = cells[0], [c for c in cells[1:] if not all(set(x) <= {"-", ":"} for x in c)]
    out = ["<table>", "<tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body]
    return "\n".join(out + ["</table>"])


def markdown_to_html(md: str, figure=None) -> tuple[str, list[str]]:
    """(HTML body, figure file names met) of report.md's Markdown subset.

    ``figure(name, alt) -> str`` renders an image reference; images are otherwise dropped.
    """
    blocks: list[str] = []
    images: list[str] = []
    para: list[str] = []
    items: list[str] = []
    table: list[str] = []

    def flush():
        if para:
            text = " ".join(para)
            cls = ""
            if text.startswith("**Verdict:"):
                # green: nothing missed; amber: only the numerics; red: physics missed
                cls = (' class="verdict consistent"' if text.startswith("**Verdict: consistent")
                       else ' class="verdict numerics"' if text.startswith("**Verdict: numerics")
                       else ' class="verdict"')
            blocks.append(f"<p{cls}>{_inline(text)}</p>")
            para.clear()
        if items:
            blocks.append("<ul>\n" + "\n".join(f"<li>{_inline(i)}</li>" for i in items)
                          + "\n</ul>")
            items.clear()
        if table:
            blocks.append(_table(table))
            table.clear()

    for line in md.splitlines():
        if line.strip().startswith(("<details", "</details")):
            flush()                     # the appendix's fold: passed through as it is
            blocks.append(line.strip())
            continue
        image = re.fullmatch(r"!\[(.*?)\]\((.+?)\)", line.strip())
        if image:
            flush()
            images.append(image.group(2))
            if figure is not None:
                blocks.append(figure(image.group(2), image.group(1)))
        elif line.startswith("#"):
            flush()
            level = len(line) - len(line.lstrip("#"))
            blocks.append(f"<h{level}>{_inline(line[level:].strip())}</h{level}>")
        elif line.startswith("- "):
            if para or table:
                flush()
            items.append(line[2:])
        elif line.startswith("|"):
            if para or items:
                flush()
            table.append(line)
        elif not line.strip():
            flush()
        else:
            if items or table:
                flush()
            para.append(line.strip())
    flush()
    return "\n".join(blocks), images


def _figure_html(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def write_report_html(path: str | Path, md_path: str | Path,
                      figures: Sequence[str | Path] = ()) -> Path:
    """Write ``report.html`` from ``report.md`` and the figures (PNG files beside it).

    The figures are placed by :data:`FIGURE_SECTIONS`; the file is written atomically.
    """
    from petsoft.diagnosis.figures import CAPTIONS

    path, md_path = Path(path), Path(md_path)
    # a figure is a path (as the caller has it) or a name beside report.md
    figures = [Path(f) if Path(f).exists() else md_path.parent / Path(f).name for f in figures]
    by_stem = {f.stem: f for f in figures if f.exists()}
    placed: set[str] = set()
    md = md_path.read_text()
    # the Markdown's own figure list is replaced by the placement below
    md, _, appendix = md.partition("\n## Figures\n")
    md += appendix[appendix.find("<details>"):] if "<details>" in appendix else ""
    sections = re.split(r"(?m)^(?=## )", md)
    body = []
    for section in sections:
        part, _ = markdown_to_html(section)
        heading = section.splitlines()[0][3:].strip() if section.startswith("## ") else ""
        figs = [_figure_html(by_stem[stem], CAPTIONS.get(stem, stem.replace("_", " ")))
                for stem in FIGURE_SECTIONS.get(heading, ()) if stem in by_stem]
        placed.update(stem for stem in FIGURE_SECTIONS.get(heading, ()) if stem in by_stem)
        rest = [s for s in by_stem if s not in placed]
        if rest and "<details>" in part:
            # figures no section claims go before the appendix
            figs += ["<h2>Other figures</h2>"] + [
                _figure_html(by_stem[s], CAPTIONS.get(s, s.replace("_", " "))) for s in rest]
            placed.update(rest)
        if "<details>" in part:
            head, _, tail = part.partition("<details>")
            body.append(head + "\n".join(figs) + "\n<details>" + tail)
        else:
            body.append("\n".join([part] + figs) if figs else part)
        continue
    rest = [s for s in by_stem if s not in placed]
    if rest:
        body.append("<h2>Other figures</h2>")
        body += [_figure_html(by_stem[s], CAPTIONS.get(s, s.replace("_", " "))) for s in rest]
    page = ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            "<title>petsoft diagnosis report</title>\n<style>" + _CSS + "</style>\n</head>\n"
            "<body>\n" + "\n".join(body) + "\n</body>\n</html>\n")
    return write_text(path, page)
