"""``ucal report`` on the README's rehearsal: its verdict agrees with its own tables, it shows
the picture of this cell's verify (not the faulty world's), its history reads as sentences, and
chromium prints it to A4 without a nearly empty page.

The rehearsal is the README's, run once for the test run (the ``rehearsal`` fixture of
``tests/system/conftest.py``), with ``--sim`` and 3 verify points: calibrate, tool-frame,
verify on the built-in cell, verify on ``examples/faulty_world.toml``. The PDF is
read without a PDF library: chromium (Skia) writes plain objects and Flate content streams, so
the pages and the glyphs each shows are counted from the file itself.
"""

from __future__ import annotations

import base64
import html
import re
import shutil
import subprocess
import zlib
from pathlib import Path
from typing import Any

import pytest
from test_report_browser import run_chromium

from doubles import ucal_here

pytestmark = pytest.mark.system

#: A page showing fewer glyphs than this is "nearly empty" (three lines of text, about).
MIN_PAGE_GLYPHS = 300
#: The rehearsal's report printed to 7 A4 pages when measured (the page before: 8, three of
#: them nearly empty); the bound leaves room for wording.
MAX_PAGES = 9


def ucal(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return ucal_here(*args, cwd=cwd)


@pytest.fixture(scope="module")
def cell(
    rehearsal: tuple[Path, list[dict[str, Any]]], tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """The rehearsal's directory (the ``rehearsal`` fixture's, copied), its report written to
    ``report.html``."""
    shared, steps = rehearsal
    for step, code in zip(steps, (0, 0, 0, 0, 1), strict=True):
        assert step["returncode"] == code, (step["args"], step["stdout"][-2000:], step["stderr"])
    d = tmp_path_factory.mktemp("rehearsal")
    shutil.copytree(shared, d, dirs_exist_ok=True)
    r = ucal(d, "report", "cell.toml", "-o", "report.html")
    assert r.returncode == 0, r.stderr
    return d


@pytest.fixture(scope="module")
def page(cell: Path) -> str:
    return (cell / "report.html").read_text(encoding="utf-8")


def section(page: str, start: str, end: str | None = None) -> str:
    text = page.split(start, 1)[1]
    return text if end is None else text.split(end, 1)[0]


def rows(table_html: str) -> list[list[str]]:
    """The cells of each body row, tags stripped."""
    body = table_html.split("<tbody>", 1)[1].split("</tbody>", 1)[0]
    return [
        [html.unescape(re.sub(r"<[^>]+>", "", c)) for c in re.findall(r"<td[^>]*>(.*?)</td>", tr)]
        for tr in re.findall(r"<tr>(.*?)</tr>", body)
    ]


def test_the_verdict_agrees_with_the_tables(page: str) -> None:
    verdict = section(page, "<h2>Verdict</h2>", "</section>")
    lost = section(page, "5. Lost motion and drift", "</section>")
    calibration = section(page, "2. Calibrations", "3. Tool frame")
    # lost motion: the verdict and the table say "not measured" for every joint, nothing
    # says "measured"
    lost_rows = rows(lost)
    assert [r[0] for r in lost_rows] == [f"J{j}" for j in range(1, 7)]
    assert all(r[-1] == "not measured" for r in lost_rows)
    assert "not measured on any joint" in lost
    assert "lost motion, J1-J6" in verdict and "lost motion: measured" not in page
    # the gauge: J1 relative to the block determined, in the base frame not determined, in the
    # verdict and in the calibration's table alike
    for part, state_column in ((verdict, -1), (calibration, 4)):
        table = next(t for t in part.split("<table")[1:] if '"col">quantity</th>' in t)
        states = {r[0]: r[state_column] for r in rows(table)}
        assert states["J1 offset, relative to the block"] == "determined", states
        assert states["J1 offset, in the robot's base frame"] == "not determined", states
        assert states["J6 offset"] == "not determined", states
    # verify: the verdict says what the caption under the picture says
    assert "verified on the built-in simulated cell: PASSED" in verdict
    verify = section(page, "4. Last verify of this cell", "</section>")
    assert "On the built-in simulated cell: verify PASSED" in verify
    # marginal in both or in neither
    assert ("PASSED (marginal)" in verdict) == ("verify PASSED (marginal)" in verify)
    assert "FAILED" not in verify


def test_the_verdict_says_what_is_not_determined_and_what_would_determine_it(
    page: str,
) -> None:
    verdict = section(page, "<h2>Verdict</h2>", "</section>")
    for words in (
        "Calibrated; verified on the built-in simulated cell",
        "at the <strong>offsets</strong> level",
        "J1 offset, relative to the block: σ 0.00",
        "<strong>J1 offset, in the robot&#x27;s base frame</strong>, not determined",
        "a doweled, levelled block",
        "<strong>tool centre along the beam (z)</strong>, not determined",
        "<strong>DH table</strong>, not determined",
        "`ucal calibrate --level full` would determine it",
        "`ucal calibrate --lost-motion` measures it",
        "the pass is not determined",
    ):
        assert words in verdict, words
    # the faulty world is named as a rehearsal on another cell, not as this cell's verdict
    assert "a rehearsal on another cell" in verdict and "Not a verdict on this cell" in verdict
    assert "FAILED" in section(verdict, "rehearsal")


def test_the_picture_is_this_cells_own_verify(cell: Path, page: str) -> None:
    own = (cell / "cell.verify.png").read_bytes()
    faulty = (cell / "cell.verify.faulty_world.png").read_bytes()
    assert own != faulty
    assert base64.b64encode(own).decode() in page
    assert base64.b64encode(faulty).decode() not in page
    assert page.count("data:image/png;base64,") == 1


def test_the_history_reads_as_sentences(page: str) -> None:
    history = section(page, "6. History: what changed, when, why")
    items = re.findall(r"<li><strong>(.*?)</li></ul></li>", history, re.S)
    assert len(items) == 2
    assert "<code>calibrate</code></strong> (write #1): joint offsets" in items[0]
    assert "why: <em>calibrate --method exact: fit ok (χ²ᵣ " in items[0]
    assert re.search(r"joint offsets \(deg\): J1 0 → 0\.\d+, J2 0 → -1\.\d+", items[0])
    assert "lost motion (deg): (absent) → not measured" in items[0]
    assert "<code>tool-frame</code></strong> (write #2): tool frame" in items[1]
    assert re.search(r"tool position \(mm\): \[0, 0, 80\] → \[0\.\d+, -0\.\d+, 80\.\d+\]", items[1])
    assert "calibration.std_block_deg" not in history  # no key dump


# ---------------------------------------------------------------------------------------------
# the PDF


def pdf_pages(data: bytes) -> list[bytes]:
    """The decompressed content of each page, in the document's order."""
    objs = {
        int(m.group(1)): m.group(2) for m in re.finditer(rb"(\d+) 0 obj\s*(.*?)endobj", data, re.S)
    }

    def stream(body: bytes) -> bytes:
        start = re.search(rb"stream\r?\n", body)
        assert start is not None
        raw = body[start.end() : body.rindex(b"endstream")]
        return zlib.decompress(raw) if b"/FlateDecode" in body[: start.start()] else raw

    def walk(body: bytes) -> list[bytes]:
        kids = re.search(rb"/Kids\s*\[(.*?)\]", body, re.S)
        if kids is None:
            return [body]
        return [p for n in re.findall(rb"(\d+) 0 R", kids.group(1)) for p in walk(objs[int(n)])]

    root = next(
        b for b in objs.values() if re.search(rb"/Type\s*/Pages\b", b) and b"/Parent" not in b
    )
    out = []
    for page in walk(root):
        contents = re.search(rb"/Contents\s*(\[.*?\]|\d+ 0 R)", page, re.S)
        assert contents is not None
        refs = re.findall(rb"(\d+) 0 R", contents.group(1))
        out.append(b"".join(stream(objs[int(n)]) for n in refs))
    return out


def glyphs(content: bytes) -> int:
    """Glyphs a page's text objects show (Skia writes 2-byte glyph ids as hex strings)."""
    return sum(
        len(re.sub(rb"\s", b"", s)) // 4
        for block in re.findall(rb"BT(.*?)ET", content, re.S)
        for s in re.findall(rb"<([0-9A-Fa-f\s]*)>", block)
    )


def test_chromium_prints_it_without_a_nearly_empty_page(cell: Path, tmp_path: Path) -> None:
    chromium = shutil.which("chromium")
    if chromium is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    pdf = tmp_path / "report.pdf"
    done = run_chromium(
        chromium,
        tmp_path / "chromium",
        "--no-pdf-header-footer",
        f"--print-to-pdf={pdf}",
        (cell / "report.html").as_uri(),
    )
    assert done.returncode == 0 and pdf.is_file(), done.stderr[-2000:]
    counts = [glyphs(p) for p in pdf_pages(pdf.read_bytes())]
    assert 1 <= len(counts) <= MAX_PAGES, counts
    assert min(counts) >= MIN_PAGE_GLYPHS, counts
