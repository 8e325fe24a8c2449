"""``ucal report``: the page holds what the profile and its history hold, and loads nothing."""

from __future__ import annotations

import base64
import json
import os
import re
from pathlib import Path

import pytest

from ucal.devices.record import Recorder, sha256_text
from ucal.errors import EXIT_USAGE
from ucal.profile import create_profile, history_dir, undo_profile, write_profile
from ucal.report import gather_report, render_page
from ucal.verify.picture import verify_picture_path

from doubles import (
    WRITTEN_OFFSETS_DEG,
    WRITTEN_TOOL_DEG,
    WRITTEN_TOOL_MM,
    calibrated_profile,
    exit_code,
)

#: A 1 x 1 grey PNG: a stand-in for the picture verify leaves beside the profile.
TINY_PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAAAAAA6fptVAAAACklEQVR4nGNgYAAAAAMAAWgmWQ0AAAAASUVORK5CYII="
)


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def external_references(page: str) -> list[str]:
    """Every src/href (and CSS url()) of the page that is not inline (data:) or in-page (#)."""
    refs = re.findall(r"""(?:src|href)\s*=\s*["']?([^"'\s>]+)""", page, re.IGNORECASE)
    refs += re.findall(r"""url\(\s*["']?([^"')]+)""", page, re.IGNORECASE)
    return [r for r in refs if not r.startswith(("data:", "#"))]


def svg_figures(page: str) -> list[str]:
    return [
        base64.b64decode(b).decode("utf-8")
        for b in re.findall(r'src="data:image/svg\+xml;base64,([A-Za-z0-9+/=]+)"', page)
    ]


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The page of a profile with a calibrate and a tool-frame write, made by the command."""
    d = tmp_path_factory.mktemp("cell")
    profile = calibrated_profile(d / "cell.toml")
    out = d / "report.html"
    assert exit_code(["report", str(profile), "-o", str(out), "-q"]) == 0
    return out.read_text(encoding="utf-8")


def test_the_page_shows_the_written_offsets_and_tool(page: str) -> None:
    for v in WRITTEN_OFFSETS_DEG:
        assert f"{v:.6f}" in page, v
    for v in [*WRITTEN_TOOL_MM, *WRITTEN_TOOL_DEG]:
        assert f"{round(v, 4) + 0.0:.4f}" in page, v
    assert "(kept from the profile)" in page
    assert "0.282" in page and ">ok<" in page  # the fit's χ²ᵣ and verdict
    assert "history write #1" in page and "history write #2" in page


def test_the_page_holds_its_figures_and_loads_nothing(page: str) -> None:
    figures = svg_figures(page)
    assert len(figures) >= 2  # offsets and tool per write
    assert all(f.lstrip().startswith("<?xml") and "<svg" in f for f in figures)
    assert external_references(page) == []
    assert "http://" not in page and "https://" not in page
    assert not re.search(r"<(script|link|iframe|object|embed)\b", page, re.IGNORECASE)
    for svg in figures:  # nor do the figures: namespaces only, no href to anything outside
        assert not re.search(r"""href\s*=\s*["'](?!#)""", svg), svg[:200]


def test_the_page_lists_every_write_and_what_it_changed(page: str) -> None:
    history = page.split("6. History: what changed, when, why", 1)[1]
    assert "joint offsets (deg): J2 0 → -1.20183, J3 0 → 1.49982" in history
    assert "tool position (mm): [0, 0, 80] → [0.315377, -0.193238, 80.1783]" in history
    assert "<code>calibrate</code></strong> (write #1)" in history
    assert "<code>tool-frame</code></strong> (write #2)" in history


def test_what_the_history_does_not_hold_is_said(page: str) -> None:
    assert "not the residual of each measurement: those come from a record of the run" in page
    assert "reason not recorded in the profile" in page
    assert "Lost motion (backlash) per joint, deg: not measured on any joint" in page
    assert "Drift of the sound speed during a run: <strong>not measured</strong>" in page
    assert "No verify of this cell beside the profile" in page
    assert "[robot] dh: the shipped table (not identified)" in page


def test_a_record_adds_residuals_and_reasons(tmp_path: Path) -> None:
    profile = calibrated_profile(tmp_path / "cell.toml")
    before = (history_dir(profile) / "0001-before.toml").read_text(encoding="utf-8")
    record = tmp_path / "run.jsonl"
    header = {
        "command": "calibrate",
        "profile_path": str(profile),
        "profile_sha256": sha256_text(before),
        "profile_text": before,
        "options": {"method": "exact", "level": "offsets"},
        "plan": [],
    }
    with Recorder(record).open(header) as rec:
        rec.end(
            {
                "joint_offsets_deg": WRITTEN_OFFSETS_DEG,
                "written": True,
                "unobservable_reasons": {"1": "one rotation with the <block> yaw"},
                "fit": {
                    "chi2_reduced": 0.2822,
                    "dof": 36,
                    "rms_tilt_deg": 3.9e-4,
                    "rms_distance_mm": 7.6e-7,
                    "worst": "base/XY",
                    "verdict": "ok",
                },
                "residuals": [
                    {"label": f"face{i}", "tilt": [0.5, -0.25 * i], "distance": 0.1}
                    for i in range(5)
                ],
            }
        )
    page = render_page(gather_report(profile, [record]))
    assert "one rotation with the &lt;block&gt; yaw" in page
    assert "0.282 (36)" in page and "0.00039 deg" in page
    assert len(svg_figures(page)) == 3  # offsets, residuals, tool
    assert "5 measurements, from the record" in page


def test_a_record_of_another_profile_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = calibrated_profile(tmp_path / "cell.toml")
    record = tmp_path / "other.jsonl"
    header = {"command": "calibrate", "profile_sha256": sha256_text("x"), "profile_text": "x"}
    with Recorder(record).open(header) as rec:
        rec.end({"written": True})
    args = ["report", str(profile), "-o", str(tmp_path / "r.html"), "--record", str(record)]
    assert exit_code(args) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f"error: {record}: ") and "no write in the history" in line
    assert not (tmp_path / "r.html").exists()


def test_everything_from_the_profile_is_escaped(tmp_path: Path) -> None:
    profile = calibrated_profile(
        tmp_path / "cell.toml", reason='calibrate <script>alert("x")</script> & more'
    )
    page = render_page(gather_report(profile))
    assert "<script" not in page
    assert "calibrate &lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; more" in page


def test_undone_identified_and_verify_picture(tmp_path: Path) -> None:
    profile = calibrated_profile(tmp_path / "cell.toml")
    dh = [
        {"theta_offset_deg": 0.0, "d_mm": 0.0, "a_mm": 50.01, "alpha_deg": -90.0},
        {"theta_offset_deg": -90.0, "d_mm": 50.0, "a_mm": 500.02, "alpha_deg": 0.0},
        {"theta_offset_deg": 90.0, "d_mm": 0.0, "a_mm": 0.0, "alpha_deg": 90.0},
        {"theta_offset_deg": 0.0, "d_mm": 550.0, "a_mm": 0.0, "alpha_deg": -90.0},
        {"theta_offset_deg": 0.0, "d_mm": 0.0, "a_mm": 0.0, "alpha_deg": 90.0},
        {"theta_offset_deg": 0.0, "d_mm": 100.0, "a_mm": 0.0, "alpha_deg": 0.0, "beta_deg": 0.01},
    ]
    write_profile(
        profile,
        {
            "calibration": {
                "joint_offsets_deg": [0.0, 0.5, 0.25, 0.0, 0.0, 0.0],
                "dh": dh,
                "dh_std": [{"d_mm": -1.0, "a_mm": 0.01, "alpha_deg": 0.001}] * 6,
            }
        },
        "calibrate --method exact --level full: fit ok (χ²ᵣ 0.9)",
    )
    report = gather_report(profile)
    assert report.identified_dh and report.calibrations[-1].dh is not None
    assert "identified by calibrate --level full" in render_page(report)
    assert "500.0200" in render_page(report)

    undo_profile(profile)
    verify_picture_path(profile).write_bytes(TINY_PNG)
    report = gather_report(profile)
    page = render_page(report)
    assert not report.identified_dh and "undone" in page
    assert report.current_calibration is report.calibrations[0]  # the write before the undone
    assert "data:image/png;base64," + base64.b64encode(TINY_PNG).decode() in page
    assert "cell.verify.png" in page


def test_a_profile_never_rewritten(tmp_path: Path) -> None:
    profile = create_profile(tmp_path / "cell.toml", "tx90l")
    page = render_page(gather_report(profile))
    assert "never calibrated" in page and "No recorded write" in page
    assert external_references(page) == []


@pytest.mark.parametrize(
    "content", [None, "schema = 1\n[robot\n", "schema = 1\n"], ids=["missing", "toml", "keys"]
)
def test_a_missing_or_invalid_profile_is_exit_2_naming_it(
    content: str | None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = tmp_path / "cell.toml"
    if content is not None:
        profile.write_text(content, encoding="utf-8")
    out = tmp_path / "report.html"
    assert exit_code(["report", str(profile), "-o", str(out)]) == EXIT_USAGE
    assert _one_error_line(capsys.readouterr().err).startswith(f"error: {profile}")
    assert not out.exists()


def test_an_unwritable_output_is_exit_2_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    profile = create_profile(tmp_path / "cell.toml", "tx90l")
    missing = tmp_path / "no-such-dir" / "report.html"
    assert exit_code(["report", str(profile), "-o", str(missing)]) == EXIT_USAGE
    assert _one_error_line(capsys.readouterr().err).startswith(f"error: {missing}: cannot write")

    locked = tmp_path / "read-only"
    locked.mkdir()
    out = locked / "report.html"
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == locked else real_access(p, mode)
    )
    assert exit_code(["report", str(profile), "-o", str(out)]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line.startswith(f"error: {out}: cannot write") and "not writable" in line
    monkeypatch.undo()

    def full_disk(*args: object, **kwargs: object) -> Path:
        raise OSError(28, "No space left on device")

    out = tmp_path / "report.html"
    monkeypatch.setattr("ucal.files.stage", full_disk)
    assert exit_code(["report", str(profile), "-o", str(out)]) == EXIT_USAGE
    line = _one_error_line(capsys.readouterr().err)
    assert line == f"error: {out}: cannot write: No space left on device"
    assert not out.exists()


def test_an_iso9283_verify_shows_its_figures(tmp_path: Path) -> None:
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    from ucal.verify.procedure import PICTURE_FACTS_KEY

    profile = calibrated_profile(tmp_path / "cell.toml")
    facts = {
        "time_utc": "2026-12-04T10:00:00+00:00",
        "profile": profile.name,
        "profile_sha256": sha256_text(profile.read_text(encoding="utf-8")),
        "cell": {"simulated": True, "world": None, "controller": None},
        "points": 5,
        "tolerance_mm": 0.5,
        "worst_mm": 0.21,
        "passed": True,
        "marginal": False,
        "measured_within_mm": 0.05,
        "before_max_mm": None,
        "after_max_mm": [0.2, 0.21, 0.1],
        "iso9283": {
            "cycles": 30,
            "side_mm": 100.0,
            "poses": [
                {
                    "name": f"P{i + 1}",
                    "ap_mm": 0.1234,
                    "ap_std_mm": 0.01,
                    "rp_mm": 0.0567,
                    "rp_std_mm": 0.004,
                }
                for i in range(5)
            ],
        },
    }
    info = PngInfo()
    info.add_text(PICTURE_FACTS_KEY, json.dumps(facts))
    Image.new("RGB", (4, 4)).save(verify_picture_path(profile), pnginfo=info)
    report = gather_report(profile)
    assert report.verify is not None and report.verify.facts is not None
    iso = report.verify.facts.iso9283
    assert iso is not None and iso.cycles == 30 and len(iso.poses) == 5
    page = render_page(report)
    assert "ISO 9283 (7.2)" in page and "100 mm cube" in page
    assert page.count("0.1234 ± 0.0100") == 5 and "0.0567 ± 0.0040" in page
