"""``ucal report``'s page rendered by a real browser: headless Debian chromium.

The DOM chromium builds from the file holds the written offsets and tool, and its screenshot is
a drawn page, not a blank one. Skipped where chromium is not installed (``apt-get install
chromium``; ``.ci/run`` installs it where it can).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from doubles import WRITTEN_OFFSETS_DEG, WRITTEN_TOOL_MM, calibrated_profile, exit_code

pytestmark = pytest.mark.system

#: Headless chromium that reaches nothing but the file: no sync, updates or first-run pages.
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
#: A loaded machine starts chromium slowly; a hung one fails the test instead of the suite.
TIMEOUT_S = 90


@pytest.fixture(scope="module")
def chromium() -> str:
    found = shutil.which("chromium")
    if found is None:
        pytest.skip("chromium is not installed (Debian: apt-get install chromium)")
    return found


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("report")
    profile = calibrated_profile(d / "cell.toml")
    out = d / "report.html"
    assert exit_code(["report", str(profile), "-o", str(out), "-q"]) == 0
    return out


def run_chromium(chromium: str, profile_dir: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [chromium, *FLAGS, f"--user-data-dir={profile_dir}", *args],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        check=False,
    )


def test_the_browser_shows_the_offsets_and_the_tool(
    chromium: str, page: Path, tmp_path: Path
) -> None:
    done = run_chromium(chromium, tmp_path / "chromium", "--dump-dom", page.as_uri())
    assert done.returncode == 0, done.stderr[-2000:]
    dom = done.stdout
    assert "<h2>2. Calibrations</h2>" in dom  # the page was parsed, not an error page
    for v in WRITTEN_OFFSETS_DEG:
        assert f"{v:.6f}" in dom, v
    for v in WRITTEN_TOOL_MM:
        assert f"{v:.4f}" in dom, v
    assert dom.count('src="data:image/svg+xml;base64,') >= 2


def test_the_screenshot_is_a_drawn_page(chromium: str, page: Path, tmp_path: Path) -> None:
    shot = tmp_path / "page.png"
    done = run_chromium(
        chromium,
        tmp_path / "chromium",
        f"--screenshot={shot}",
        "--window-size=1200,3000",
        page.as_uri(),
    )
    assert done.returncode == 0 and shot.exists(), done.stderr[-2000:]
    from matplotlib.image import imread

    grey = imread(shot)[..., :3].mean(axis=-1)  # 0 black … 1 white
    assert grey.shape == (3000, 1200)
    dark = grey < 0.5
    assert dark.mean() > 0.01, "the screenshot is (nearly) blank"
    # text at the top (the title), and drawing further down (tables and figures)
    rows_with_ink = np.flatnonzero(dark.any(axis=1))
    assert rows_with_ink[0] < 200 and rows_with_ink[-1] > 2000
