"""A profile key the connected device cannot take is refused before the first motion (exit 2,
naming the key and the device), not at the first reading that needs it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from ucal.profile import default_profile_text


def test_averages_the_pulser_cannot_take_are_refused_before_any_motion(
    tmp_path: Path, run_main: Callable[[list[str]], tuple[int, str, str]]
) -> None:
    """ucal's register map takes 1 … 1024 averages: 2000 passed ``profile validate`` (the key's
    own range is the instrument's) and the run moved 55 times before a ``ValueError`` ended it
    with exit 1."""
    p = tmp_path / "cell.toml"
    text = default_profile_text("tx90l")
    assert "tof_averages = 16 " in text
    text = text.replace("tof_averages = 16 ", "tof_averages = 2000 ", 1)
    p.write_text(text, encoding="utf-8")
    record = tmp_path / "run.jsonl"
    code, out, _ = run_main(
        ["calibrate", str(p), "--sim", "--yes", "--json", "--record", str(record)]
    )
    assert code == 2, out
    error = json.loads(out.strip().splitlines()[-1])
    assert error["exit_code"] == 2
    message = error["error"]
    assert message.startswith(f"{p}: procedure.tof_averages: 2000 averages")
    assert "the pulser at modbus-tcp://127.0.0.1:" in message
    assert "out of range [1, 1024]" in message
    calls = [json.loads(line).get("call") for line in record.read_text().splitlines()]
    assert not [c for c in calls if c and c.startswith("controller.")]  # nothing moved
    assert p.read_text(encoding="utf-8") == text
