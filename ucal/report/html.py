"""The report page's HTML pieces: its stylesheet, escaping, numbers and times as shown, tables,
sections, figures and notes (``ucal.report.page`` puts them together)."""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

CSS = """
:root { color-scheme: light; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", "Liberation Sans", Arial, Helvetica, sans-serif;
  font-size: 10.5pt; line-height: 1.4; color: #000; background: #fff;
  max-width: 190mm; margin: 0 auto; padding: 8mm 6mm; }
h1 { font-size: 17pt; margin: 0 0 2mm; }
h2 { font-size: 13.5pt; border-bottom: 1.5pt solid #000; padding-bottom: 1mm; margin: 8mm 0 3mm; }
h3 { font-size: 11pt; margin: 5mm 0 2mm; }
h2, h3 { break-after: avoid; page-break-after: avoid; }
p { margin: 1.5mm 0; }
table { border-collapse: collapse; margin: 2mm 0 3mm; font-size: 9.5pt; }
th, td { border: 0.6pt solid #888; padding: 0.8mm 2mm; vertical-align: top; text-align: left; }
th { background: #ececec; font-weight: bold; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
thead { display: table-header-group; }
tr { break-inside: avoid; page-break-inside: avoid; }
table.kv th { width: 34mm; }
table.wide { width: 100%; }
.meta td, .meta th { border: none; padding: 0.3mm 3mm 0.3mm 0; background: none; }
.note { border-left: 2.5pt solid #666; padding: 1mm 3mm; margin: 2mm 0; background: #f4f4f4; }
.state { font-weight: bold; }
.nowrap { white-space: nowrap; }
.bad { font-weight: bold; text-decoration: underline; }
.muted { color: #444; }
code { font-family: "DejaVu Sans Mono", "Liberation Mono", monospace; font-size: 9pt; }
figure { margin: 3mm 0; break-inside: avoid; page-break-inside: avoid; }
figure img { display: block; width: 100%; height: auto; border: 0.6pt solid #bbb; }
figcaption { font-size: 9pt; color: #222; margin-top: 1mm; }
ul.changes { margin: 0; padding-left: 4mm; }
ul.changes li { margin: 0; }
section.calibration { break-inside: auto; }
section.verdict { border: 1.2pt solid #000; padding: 1mm 4mm 2mm; margin: 4mm 0; }
section.verdict h2 { margin-top: 2mm; }
p.lead { font-size: 11.5pt; margin: 2mm 0 3mm; }
ul.plain { margin: 0; padding-left: 4mm; }
ul.plain li { margin: 0.5mm 0; }
ol.history { padding-left: 6mm; }
ol.history li { margin: 0 0 2mm; break-inside: avoid; page-break-inside: avoid; }
table.short, figure, .note { break-inside: avoid; page-break-inside: avoid; }
@page { size: A4; margin: 14mm 12mm 16mm; }
@media print {
  body { max-width: none; padding: 0; font-size: 9.5pt; }
  h2 { margin-top: 6mm; }
  a { color: #000; text-decoration: none; }
  * { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
}
"""


def e(value: Any) -> str:
    """``value`` as escaped HTML text."""
    return html.escape(str(value), quote=True)


def num(value: float | None, digits: int = 4) -> str:
    """A number with ``digits`` decimals; an em dash for None or NaN."""
    if value is None or not np.isfinite(value):
        return "—"
    return f"{round(float(value), digits) + 0.0:.{digits}f}"  # + 0.0: no "-0.0000"


def nums(values: Iterable[float] | None, digits: int = 4, unit: str = "") -> str:
    if values is None:
        return "—"
    text = ", ".join(num(float(v), digits) for v in values)
    return f"[{text}]" + (f" {unit}" if unit else "")


def when(iso: str | None) -> str:
    """An ISO time as ``2026-01-02 10:00:00 UTC`` (as written when not ISO)."""
    if not iso:
        return "—"
    return iso.replace("T", " ").replace("+00:00", " UTC")


def when_cell(iso: str | None) -> str:
    """An ISO time on two lines (date, then time): narrow table columns."""
    date, _, clock = when(iso).partition(" ")
    return f'<span class="nowrap">{e(date)}</span><br><span class="nowrap">{e(clock)}</span>'


def table(
    head: Sequence[str], rows: Iterable[Sequence[str]], numeric: Sequence[bool], cls: str = ""
) -> str:
    """A table of already escaped cells."""
    th = "".join(
        f'<th{" class=num" if n else ""} scope="col">{h}</th>'
        for h, n in zip(head, numeric, strict=True)
    )
    body = "".join(
        "<tr>"
        + "".join(
            f"<td{' class=num' if n else ''}>{c}</td>" for c, n in zip(row, numeric, strict=True)
        )
        + "</tr>"
        for row in rows
    )
    return f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def kv(rows: Iterable[tuple[str, str]]) -> str:
    body = "".join(f'<tr><th scope="row">{k}</th><td>{v}</td></tr>' for k, v in rows)
    return f'<table class="kv"><tbody>{body}</tbody></table>'


def part(title: str) -> str:
    """The opening of a numbered part of the page."""
    return f'<section class="part"><h2>{title}</h2>'


def empty_part(title: str, why: str) -> str:
    """A part with nothing to show: its title and why (``why``: HTML, one paragraph)."""
    return f"{part(title)}\n<p>{why}</p></section>"


def figure(uri: str, alt: str, caption: str) -> str:
    return f'<figure><img src="{e(uri)}" alt="{e(alt)}"><figcaption>{caption}</figcaption></figure>'


def note(text: str) -> str:
    return f'<p class="note">{text}</p>'
