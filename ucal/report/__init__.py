"""``ucal report``: one self-contained HTML page of a cell as its profile and history hold it.

:mod:`ucal.report.gather` reads the profile, its history and the records of its calibrate runs
into a :class:`CellReport`; :mod:`ucal.report.figures` draws; :mod:`ucal.report.page` writes the
page. :func:`write_report` puts the page on disk.
"""

from __future__ import annotations

from pathlib import Path

from ucal import files
from ucal.errors import InputError
from ucal.report.gather import CellReport, gather_report
from ucal.report.page import render_page

__all__ = ["CellReport", "gather_report", "render_page", "write_report"]


def write_report(path: str | Path, page: str) -> None:
    """Write ``page`` to ``path`` atomically (temporary file beside it, then renamed); raise
    :class:`InputError` (exit 2) naming the file when it cannot be written."""
    out = Path(path)
    try:
        files.commit(files.stage(out, page.encode("utf-8")), out)
    except OSError as e:
        raise InputError(f"{out}: cannot write: {e.strerror or e}") from None
