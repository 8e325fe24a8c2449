"""A cell whose pulser-receiver is set by hand (``[pulser] kind = "manual"``, ``--pulser
manual://``), the digitiser alone beside it, from the command line:

* it calibrates in ``--sim`` (world ``[pulser] kind`` follows the profile) and through
  ``ucal sim serve``, which serves the oscilloscope alone; ``ucal status --profile`` shows the
  pulser as set by hand with its declaration, the digitiser's identity and the check;
* a declaration the records disagree with (the panel's true gain, the transducer's frequency, a
  gain that clips) is refused, exit 2 naming the key and the measured value, before any motion;
  where the arm stands over no echo, the first echo's frequency before it is used;
* the profile and the URL must agree on whether the pulser is set by hand.

The runs read a reference echo from a file (``[pulser] reference_echo``): the capture on the
block is the ascii-scpi cell's to test, and a file keeps these runs short.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ucal.profile import default_profile_text
from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG
from ucal.sim.rf import RfOutput
from ucal.sim.serve import serving

from doubles import counting_moves, finished_json, noisy_world, std_of

pytestmark = pytest.mark.system

PANEL = '[pulser]\nkind = "manual"\ngain_db = 20.0\nprf_hz = 500.0\nreference_echo = "ref.csv"\n'
#: The calibration pose of the profile: the beam straight down on the block's XY face.
FACING_THE_BLOCK = "[30.53, 31.15, 109.49, 0.0, 39.36, 30.54]"


def cell_set_by_hand(directory: Path, name: str = "cell") -> Path:
    """A tx90l profile whose pulser is set by hand (20 dB, 500 Hz), with the simulated
    transducer's echo at 100 MS/s as its reference (``ref.csv``)."""
    write_reference(directory / "ref.csv", 25.0, 100.0)
    path = directory / f"{name}.toml"
    path.write_text(default_profile_text("tx90l") + "\n" + PANEL)
    return path


def write_reference(path: Path, frequency_mhz: float, sample_rate_mhz: float) -> None:
    """The simulated transducer's echo as a record at ``sample_rate_mhz`` holds it, its arrival
    at ``t_ns = 0``, over where it is above 1e-4 of its peak and 8 samples either side."""
    dt_ns = 1e3 / sample_rate_mhz
    shape = RfOutput(frequency_mhz, 0.0, 0).shape(dt_ns)
    arrival = len(shape.waveform) // 4
    fine = round(dt_ns / shape.waveform_dt_ns)
    index = np.arange(arrival % fine, len(shape.waveform), fine)
    t_ns = (index - arrival) * shape.waveform_dt_ns
    echo = shape.waveform[index]
    above = np.flatnonzero(np.abs(echo) > 1e-4)
    keep = slice(above[0] - 8, above[-1] + 9)
    rows = "".join(f"{t:.6f},{v:.9f}\n" for t, v in zip(t_ns[keep], echo[keep], strict=True))
    path.write_text("t_ns,reference\n" + rows)


def written_and_covered(result: dict) -> None:
    """Written, the fit ok, timed from the A-scans against the profile's reference, the demo
    offsets within 3 reported sigmas."""
    std = std_of(result)
    seen = np.isfinite(std)
    assert result["written"] and result["fit"]["verdict"] == "ok", result["fit"]
    assert (result["timing"], result["reference_echo"]["source"]) == ("ascan", "profile")
    off = np.abs(np.subtract(result["joint_offsets_deg"], DEMO_JOINT_OFFSETS_DEG))
    assert np.all(off[seen] <= 3 * std[seen]), (off, std)


def ucal(*args: str) -> tuple[int, dict, str]:
    """``ucal ARGS --json`` in a process of its own: its exit code, JSON object and stderr."""
    done = subprocess.run(
        [sys.executable, "-m", "ucal", *args, "--json"],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        timeout=500,
        check=False,
    )
    return done.returncode, json.loads(done.stdout or "{}"), done.stderr[-2000:]


@pytest.mark.long
@pytest.mark.timeout(600)
def test_a_cell_set_by_hand_calibrates_in_sim_and_through_sim_serve(tmp_path: Path) -> None:
    # the same truth twice: the lock-step rehearsal's state stream the released server's (on
    # simulated time a frame costs work, not waiting), the served cell's ten times faster
    (tmp_path / "rehearsed.world.toml").write_text(noisy_world(sample_rate_mhz=100.0))
    (tmp_path / "world.toml").write_text(noisy_world(served_at_a_tenth=True, sample_rate_mhz=100.0))
    rehearsed_profile = cell_set_by_hand(tmp_path, "rehearsed")
    in_process = subprocess.Popen(
        [sys.executable, "-m", "ucal", "calibrate", str(rehearsed_profile)]
        + ["--sim", str(tmp_path / "rehearsed.world.toml"), "--yes", "--json", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    served_profile = cell_set_by_hand(tmp_path, "served")
    with serving(
        "--world", "world.toml", "--profile", "served.toml", "--time-scale", "0.1", cwd=tmp_path
    ) as urls:
        assert urls["pulser"] == "manual://" and urls["digitizer"].startswith("visa://")
        cell = ["--controller", urls["controller"], "--pulser", urls["pulser"]]
        cell += ["--digitizer", urls["digitizer"]]
        status = ucal("status", *cell, "--profile", str(served_profile))
        served = ucal("calibrate", str(served_profile), *cell, "--yes", "-q")
    assert status[0] == 0, status[2]
    pulser = status[1]["pulser"]
    assert pulser["set_by_hand"] is True and pulser["declared"]["gain_db"] == 20.0
    assert pulser["declared"]["prf_hz"] == 500.0
    assert pulser["digitizer"]["model"] == "DSOX3024T"
    assert pulser["check"]["verdict"] == "ok" and not pulser["check"]["clipped"]
    assert served[0] == 0, served[2]
    for result in (finished_json(in_process), served[1]):
        written_and_covered(result)


@pytest.mark.parametrize(
    "world, refusal",
    [
        # the panel at 60 dB: its noise is 40 dB above the declared gain's
        (
            "[pulser]\ngain_db = 60.0\nsample_rate_mhz = 100.0\n",
            r"pulser\.gain_db: 20 dB, but the A-scans' noise says 6\d\.\d dB",
        ),
        # a 15 MHz transducer, the arm standing over the block: its echo says so
        (
            f"[robot]\ninitial_joints_deg = {FACING_THE_BLOCK}\n[transducer]\n"
            "frequency_mhz = 15.0\n[pulser]\nsample_rate_mhz = 100.0\n",
            r"transducer\.frequency_mhz: 25 MHz, but the echo where the arm stands is centred "
            r"at 1[45]\.\d\d MHz",
        ),
        # the panel at 40 dB over the block: the echo is clipped
        (
            f"[robot]\ninitial_joints_deg = {FACING_THE_BLOCK}\n[pulser]\ngain_db = 40.0\n"
            "sample_rate_mhz = 100.0\n",
            r"pulser\.gain_db: 20 dB, but the A-scans where the arm stands are clipped",
        ),
    ],
)
def test_a_declaration_the_records_disagree_with_is_refused_before_any_motion(
    run_main, monkeypatch: pytest.MonkeyPatch, tmp_path: Path, world: str, refusal: str
) -> None:
    profile = cell_set_by_hand(tmp_path)
    before = profile.read_bytes()
    (tmp_path / "world.toml").write_text(world)
    moves = counting_moves(monkeypatch)
    code, out, _ = run_main(
        ["calibrate", str(profile), "--sim", str(tmp_path / "world.toml"), "--yes", "--json"]
    )
    error = json.loads(out)
    assert (code, error["exit_code"]) == (2, 2), error
    assert error["error"].startswith(f"{profile}: ")
    assert re.search(refusal, error["error"]), error["error"]
    assert moves["n"] == 0
    assert profile.read_bytes() == before


def test_a_panel_whose_period_the_gate_outlasts_is_refused_naming_its_prf(
    run_main, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    profile = cell_set_by_hand(tmp_path)
    profile.write_text(profile.read_text().replace("prf_hz = 500.0", "prf_hz = 5000.0"))
    moves = counting_moves(monkeypatch)
    code, out, _ = run_main(["calibrate", str(profile), "--sim", "--yes", "--json"])
    assert code == 2 and moves["n"] == 0
    assert json.loads(out)["error"] == (
        f"{profile}: pulser.prf_hz: the pulser at manual:// cannot take the procedures' "
        "settings: gate 5 + 400 µs ends after the pulse repetition period (200 µs at the front "
        "panel's 5000 Hz)"
    )


def test_the_first_echo_of_another_frequency_is_refused_before_it_is_used(
    run_main, tmp_path: Path
) -> None:
    """The arm standing over no echo: the frequency is the first timed echo's to check."""
    profile = cell_set_by_hand(tmp_path)
    before = profile.read_bytes()
    world = "[transducer]\nfrequency_mhz = 15.0\n[pulser]\nsample_rate_mhz = 100.0\n"
    (tmp_path / "world.toml").write_text(world)
    code, out, _ = run_main(
        ["calibrate", str(profile), "--sim", str(tmp_path / "world.toml"), "--yes", "--json"]
    )
    assert code == 2
    assert re.search(
        r"transducer\.frequency_mhz: 25 MHz, but the echo first timed is centred at 1[45]\.\d\d",
        json.loads(out)["error"],
    )
    assert profile.read_bytes() == before


@pytest.mark.parametrize(
    "pulser, set_by_hand, message",
    [
        (["--pulser", "modbus-tcp://127.0.0.1:502"], True, "pulser.kind: 'manual': the cell's"),
        (
            ["--pulser", "manual://", "--digitizer", "visa://TCPIP::127.0.0.1::5025::SOCKET"],
            False,
            "pulser.kind: the pulser at manual:// is set by hand",
        ),
        (["--pulser", "manual://"], True, "does not digitise: give its digitiser"),
    ],
)
def test_the_profile_and_the_url_agree_on_a_pulser_set_by_hand(
    run_main, monkeypatch: pytest.MonkeyPatch, tmp_path: Path, pulser, set_by_hand, message
) -> None:
    for name in ("UCAL_SIM", "UCAL_CONTROLLER", "UCAL_PULSER", "UCAL_DIGITIZER"):
        monkeypatch.delenv(name, raising=False)
    profile = cell_set_by_hand(tmp_path) if set_by_hand else tmp_path / "cell.toml"
    if not set_by_hand:
        profile.write_text(default_profile_text("tx90l"))
    moves = counting_moves(monkeypatch)
    code, out, _ = run_main(
        ["calibrate", str(profile), "--controller", "tcp://127.0.0.1:9", *pulser, "--yes"]
        + ["--json"]
    )
    assert code == 2 and message in json.loads(out)["error"]
    assert moves["n"] == 0
    code, out, _ = run_main(
        ["status", "--controller", "tcp://127.0.0.1:9", "--pulser", "manual://", "--json"]
        + ["--digitizer", "visa://TCPIP::127.0.0.1::5025::SOCKET"]
    )
    assert code == 2 and "give --profile PROFILE" in json.loads(out)["error"]
