"""A self-contained HTML report: the headline, the conclusions in words, figures and tables,
the provenance. Pure: data in, one string out; figures embedded (PNG as base64 data URIs, SVG
inline). `markdown_to_html` converts exactly the Markdown subset the table writer produces
(headings, bullets, pipe tables, paragraphs, **bold**, `code`, [links](x.md)).
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field

from sewtol.errors import ParameterError

CSS = """
body{font-family:"DejaVu Sans",Arial,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;
color:#111;line-height:1.4;font-size:14px;overflow-wrap:break-word}
div.table,div.wide{overflow-x:auto}
h1{font-size:1.6em;border-bottom:2px solid #333}h2{font-size:1.3em;border-bottom:1px solid #999;
margin-top:2em}h3{font-size:1.1em}
table{border-collapse:collapse;margin:.5em 0 1em;font-size:12px}
th,td{border:1px solid #bbb;padding:2px 6px;text-align:right}th{background:#eee}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img,figure svg{max-width:100%;height:auto}
figcaption{font-size:12px;color:#333}
section.headline{border:2px solid #346;padding:.3em .8em;margin:.5em 0 1em;font-size:15px}
section.headline p{margin:.35em 0}
section.conclusions{background:#f5f8ff;border:1px solid #9ab;padding:.5em 1em}
.holds{color:#060;font-weight:bold}.fails{color:#a00;font-weight:bold}
.dependent{color:#a40;font-weight:bold}
details{margin:.5em 0}summary{cursor:pointer}
code{background:#f2f2f2;padding:0 2px}
@media print{details{display:block}section{page-break-inside:avoid}}
"""


@dataclass(frozen=True)
class Figure:
    """One figure: a file name (the anchor), a caption, the bytes and their format."""
    name: str
    caption: str
    data: bytes
    fmt: str = "png"

    def __post_init__(self):
        if self.fmt not in ("png", "svg"):
            raise ParameterError("figure format", "must be png or svg to embed in HTML", self.fmt)


@dataclass(frozen=True)
class Section:
    """A heading and its body: figures, then tables as (file stem, Markdown as the table writer
    makes it; the stem is the anchor other tables' links point at), then free Markdown."""
    heading: str
    tables: tuple[tuple[str, str], ...] = ()
    figures: tuple[Figure, ...] = ()
    markdown: str = ""
    anchor: str = ""
    collapse_rows: int = 40  # pipe tables longer than this fold into <details>


# a statement's verdict over the frames (or the source's readings) -> its CSS class; '' is plain
VERDICT_CLASSES = {"holds in every frame": "holds", "fails in every frame": "fails",
                   "frame-dependent": "dependent", "holds under every reading": "holds",
                   "reading-dependent": "dependent"}


@dataclass(frozen=True)
class Conclusion:
    """One statement; verdict one of VERDICT_CLASSES or '' (plain)."""
    text: str
    verdict: str = ""

    def __post_init__(self):
        if self.verdict and self.verdict not in VERDICT_CLASSES:
            raise ParameterError("verdict", f"must be one of {', '.join(VERDICT_CLASSES)} or "
                                 "empty", self.verdict)


@dataclass(frozen=True)
class Report:
    """The page. `headline`: the lines a reader sees first, as (label, text) pairs (the needle
    report: the yield, what to do, how far it depends on the frame), before everything else."""
    title: str
    intro: str
    conclusions: dict[str, list[Conclusion]]
    sections: list[Section]
    provenance: dict = field(default_factory=dict)
    headline: tuple[tuple[str, str], ...] = ()


def _inline(text: str) -> str:
    """Escape, then the inline Markdown the reports use: `code`, **bold**, [text](target)."""
    out = html.escape(text, quote=False)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    out = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", out)

    def link(m):
        target = m.group(2)
        # a link to another table of the report points at that table's section here
        if re.fullmatch(r"[\w.+\-]+\.md", target):
            target = "#" + anchor_of(target[:-3])
        return f'<a href="{html.escape(target)}">{m.group(1)}</a>'

    return re.sub(r"\[([^\]]+)\]\(([^)\s]+)\)", link, out)


def anchor_of(name: str) -> str:
    return "t-" + re.sub(r"[^\w-]", "_", name)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _table(rows: list[str], collapse_rows: int) -> str:
    head = _cells(rows[0])
    body = [_cells(r) for r in rows[2:]]
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head)
           + "</tr></thead>", "<tbody>"]
    out += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body]
    out.append("</tbody></table>")
    text = "\n".join(out)
    if len(body) > collapse_rows:
        return f"<details><summary>{len(body)} rows (click to open)</summary>\n{text}\n</details>"
    return text


def markdown_to_html(md: str, collapse_rows: int = 40, shift: int = 1) -> str:
    """The Markdown subset the report tables use, as HTML; headings move down by `shift`."""
    out, para, items, table = [], [], [], []

    def flush():
        if para:
            out.append("<p>" + _inline(" ".join(para)) + "</p>")
            para.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()
        if table:
            out.append(_table(table, collapse_rows))
            table.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|"):
            if not table:
                flush()
            table.append(s)
            continue
        if table:
            flush()
        m = re.match(r"(#{1,6})\s+(.*)", s)
        if m:
            flush()
            level = min(6, len(m.group(1)) + shift)
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
        elif s.startswith(("- ", "* ")):
            if para:
                flush()
            items.append(s[2:])
        elif not s:
            flush()
        elif items:
            items[-1] += " " + s
        else:
            para.append(s)
    flush()
    return "\n".join(out)


def figure_html(fig: Figure) -> str:
    """The figure embedded: PNG as a base64 data URI, SVG inline (its XML prolog dropped)."""
    cap = f"<figcaption>{_inline(fig.caption)}</figcaption>"
    if fig.fmt == "png":
        src = "data:image/png;base64," + base64.b64encode(fig.data).decode("ascii")
        body = f'<img src="{src}" alt="{html.escape(fig.caption)}">'
    else:
        text = fig.data.decode("utf-8")
        # several SVGs in one page: each one's ids (and the references to them) get the
        # figure's name as a prefix, so no two figures share an id
        prefix = re.sub(r"[^\w-]", "_", fig.name) + "-"
        body = text[text.index("<svg"):]
        body = re.sub(r'\bid="', f'id="{prefix}', body)
        body = re.sub(r"url\(#", f"url(#{prefix}", body)
        body = re.sub(r'href="#', f'href="#{prefix}', body)
    return f'<figure id="f-{anchor_of(fig.name)[2:]}">\n{body}\n{cap}\n</figure>'


def _provenance(prov: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{_inline(str(v))}</td></tr>"
                   for k, v in prov.items())
    return f'<div class="wide"><table><tbody>{rows}</tbody></table></div>'


def render(report: Report) -> str:
    """The whole page. The conclusions come first, right after the title and a short intro."""
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(report.title)}</title>", f"<style>{CSS}</style>", "</head>",
             "<body>", f"<h1>{html.escape(report.title)}</h1>"]
    if report.headline:
        parts.append('<section class="headline" id="headline">')
        parts += [f'<p class="headline-line"><strong>{html.escape(label)}</strong>: '
                  f"{_inline(text)}</p>" for label, text in report.headline]
        parts.append("</section>")
    parts += ['<section class="conclusions" id="conclusions">', "<h2>Conclusions</h2>"]
    if report.intro:
        parts.append(f"<p>{_inline(report.intro)}</p>")
    for heading, items in report.conclusions.items():
        parts.append(f"<h3>{_inline(heading)}</h3>")
        lis = []
        for c in items:
            tag = ""
            if c.verdict:
                cls = VERDICT_CLASSES[c.verdict]
                tag = f'<span class="{cls}">{html.escape(c.verdict)}</span>: '
            lis.append(f"<li>{tag}{_inline(c.text)}</li>")
        parts.append("<ul>" + "".join(lis) + "</ul>")
    parts.append("</section>")
    contents = "".join(f'<li><a href="#{anchor_of(s.anchor or s.heading)}">'
                       f"{html.escape(s.heading)}</a></li>" for s in report.sections)
    parts.append(f'<nav><h2>Contents</h2><ul>{contents}<li><a href="#provenance">Provenance'
                 "</a></li></ul></nav>")
    for s in report.sections:
        parts.append(f'<section id="{anchor_of(s.anchor or s.heading)}">')
        parts.append(f"<h2>{html.escape(s.heading)}</h2>")
        parts += [figure_html(f) for f in s.figures]
        for name, md in s.tables:
            parts.append(f'<div class="table" id="{anchor_of(name)}">')
            parts.append(markdown_to_html(md, s.collapse_rows, shift=2))
            parts.append("</div>")
        if s.markdown:
            parts.append(markdown_to_html(s.markdown, s.collapse_rows, shift=2))
        parts.append("</section>")
    parts += ['<section id="provenance">', "<h2>Provenance</h2>", _provenance(report.provenance),
              "</section>", "</body>", "</html>"]
    return "\n".join(parts) + "\n"


def markdown_index(report: Report, html_name: str = "report.html") -> str:
    """The same report as a Markdown index: the conclusions, then per section its tables as
    links and its figures as images (the figure files beside it), then the provenance."""
    lines = [f"# {report.title}", ""]
    if report.headline:
        lines += [f"- **{label}**: {text}" for label, text in report.headline] + [""]
    lines += [report.intro, "",
             f"[{html_name}]({html_name}): this page as one self-contained HTML file "
             "(figures embedded).", ""]
    for heading, items in report.conclusions.items():
        lines += [f"## {heading}", ""]
        lines += [f"- {'**' + c.verdict + '**: ' if c.verdict else ''}{c.text}" for c in items]
        lines.append("")
    lines += ["## Tables and figures", ""]
    for s in report.sections:
        lines += [f"### {s.heading}", ""]
        if s.tables:
            lines += ["Tables: " + ", ".join(f"[{name}.md]({name}.md)" for name, _ in s.tables),
                      ""]
        if s.figures:
            lines += [f"![{f.caption}]({f.name}.{f.fmt})" for f in s.figures] + [""]
    lines += ["## Provenance", ""] + [f"- {k}: {v}" for k, v in report.provenance.items()]
    return "\n".join(lines) + "\n"
