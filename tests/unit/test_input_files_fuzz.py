"""The other files a user hands ucal, edited as a hand edits them: a pulser's register map, a
tank thermometer's log, a scan for ``ucal path``, A-scans for ``ucal echo``. Each is read or
refused with exit 2 naming the file (SPEC.md, exit codes), never an internal error (exit 1) or
a traceback; ``path`` may also refuse a reachable file's pose for safety (exit 4)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.pulser.map_file import SHIPPED_MAP_PATH
from ucal.errors import ProfileError
from ucal.profile import create_profile
from ucal.thermometer import read_log

from doubles import exit_code, hand_edited

ROOT = Path(__file__).resolve().parents[2]
MAP_LINES = SHIPPED_MAP_PATH.read_text(encoding="utf-8").splitlines(keepends=True)
SCAN_LINES = (ROOT / "examples" / "scan.csv").read_text(encoding="utf-8").splitlines(True)[:40]
TOKENS = ['"x"', "-1", "0", "65536", "1e300", "nan", "inf", "[]", "[1, 2]", "{}", "true", '"']
FIELDS = ["", "x", "-1", "0", "1e300", "nan", "inf", "2026-12-02T13:00:00Z", "20.5", "1e-3"]


def one_error_line(err: str) -> bool:
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    return len(errors) == 1 and "Traceback" not in err


@pytest.fixture(scope="module")
def cell_dir() -> Path:
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_an_edited_register_map_is_read_or_refused_by_name(
    cell_dir: Path, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    text = data.draw(hand_edited(MAP_LINES, TOKENS))
    profile = cell_dir / "cell.toml"
    if not profile.exists():
        create_profile(profile, "tx90l")
        with profile.open("a", encoding="utf-8") as f:
            f.write('\n[pulser]\nregister_map = "map.toml"\n')
    (cell_dir / "map.toml").write_text(text, encoding="utf-8")
    code = exit_code(["profile", "validate", str(profile)])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    if code == 2:
        assert one_error_line(err) and "map.toml" in err, err


@settings(max_examples=300)
@given(
    rows=st.lists(
        st.lists(st.sampled_from(FIELDS), min_size=0, max_size=3).map(",".join), max_size=6
    ),
    header=st.sampled_from(["", "time_min,temperature_c\n", "time,temperature_c\n", "#x\n"]),
    end=st.sampled_from(["", "\n"]),
)
def test_a_thermometer_log_is_read_or_refused_by_name(
    rows: list[str], header: str, end: str
) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "tank.csv"
        path.write_text(header + "\n".join(rows) + end, encoding="utf-8")
        try:
            log_ = read_log(path, "--thermometer")
        except ProfileError as e:
            assert str(e).startswith(f"{path}") and "\n" not in str(e)
            return
        assert len(log_.time_min) >= 1


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_an_edited_scan_is_turned_into_joints_or_refused(
    cell_dir: Path, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    text = data.draw(hand_edited(SCAN_LINES, FIELDS))
    profile = cell_dir / "scan-cell.toml"
    if not profile.exists():
        create_profile(profile, "tx90l")
    scan = cell_dir / "scan.csv"
    scan.write_text(text, encoding="utf-8")
    code = exit_code(["path", str(profile), str(scan), "-o", str(cell_dir / "joints.csv")])
    err = capsys.readouterr().err
    assert code in (0, 2, 4), err
    if code:
        assert one_error_line(err), err


@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rows=st.lists(
        st.lists(st.sampled_from(FIELDS), min_size=1, max_size=3).map(",".join),
        min_size=0,
        max_size=12,
    ),
    header=st.sampled_from(["", "t_ns,a\n", "t_ns,a,b\n", "t,a\n"]),
)
def test_an_edited_ascan_file_is_timed_or_refused_by_name(
    cell_dir: Path, capsys: pytest.CaptureFixture[str], rows: list[str], header: str
) -> None:
    path = cell_dir / "scans.csv"
    path.write_text(header + "\n".join(rows) + "\n", encoding="utf-8")
    code = exit_code(["echo", str(path), "--json"])
    err = capsys.readouterr().err
    assert code in (0, 2, 3), err
    if code:
        assert one_error_line(err) and "scans.csv" in err, err
