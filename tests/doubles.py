"""Test doubles and helpers shared by the test tiers (importable as ``doubles``: pytest puts the
directory of the root ``conftest.py`` on ``sys.path``).

* :func:`exit_code` — the ``ucal`` entry point run in this process, its exit code;
* :func:`ucal_here` — the same with its stdout and stderr, shaped as a finished process;
* :func:`terminal_typed` — a terminal for stdin on which the user has typed an answer;
* :func:`crc16_modbus` — the reference CRC of a Modbus RTU frame, bit by bit;
* :class:`ScriptedPort` — a serial port that plays a dialogue of expected requests and replies,
  in the style of pymeasure's ``expected_protocol``;
* :class:`ScriptedVisaResource` — the same for a PyVISA message-based resource;
* :class:`QuietPulser` — a pulser-receiver that accepts every setting; subclasses say what a
  gate reads;
* :class:`FakeController` — a robot controller whose arm is at once where it was sent, at rest;
* :func:`noisy_world` — a world file's text: the demo's offsets and noise, and ``[pulser]`` keys;
* :func:`finished_json` — a ``ucal ... --json`` process waited for: exit 0, its JSON object;
* :func:`std_of` — a result's ``std_deg`` with NaN where a joint was not determined;
* :func:`noisy_face` — one face measured at normal incidence on a true cell, with noise;
* :func:`measured_cell` — noisy face measurements of a true cell (a DH table, offsets, block,
  water) at a plan's postures, without a simulator;
* :func:`calibrated_profile` — a profile with a history (a calibrate and a tool-frame write),
  written by the profile's own write functions in a fraction of a second;
* :func:`once_per_run` — what a costly fixture makes, made once for the whole test run (one
  xdist worker makes it, the others wait for it and read it).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import pytest

from drivers.controller.base import ControllerStatus, JointSample, RobotController
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings
from ucal.acoustics import sound_speed_m_s
from ucal.cli import main
from ucal.kinematics.rotations import rpy_to_matrix
from ucal.model.geometry import CellGeometry, FaceMeasurement, beam_and_tcp
from ucal.model.kinematic import ideal_measurements
from ucal.model.wrist import aim_wrist
from ucal.profile import create_profile, write_profile

try:
    import fcntl
except ImportError:  # not POSIX: every worker makes its own
    fcntl = None  # type: ignore[assignment]

#: How much larger one run's J2-J5 stds may be than another's on the same world by their draws
#: alone: a joint's std follows its faces' tilt stds, each fitted from its own probe grid's few
#: residuals (0.1-1.8 mdeg from face to face and draw to draw), so two runs that time their
#: echoes apart, and so draw their noise apart, differ by tens of percent: A-scan over gate
#: timing, shaped echoes, seeds 1-6, 0.54-1.41 on J2-J5 (within 15 % on four seeds of six).
DRAW_STD_RATIO = 1.5

#: What :func:`calibrated_profile` writes (as ``calibrate`` and ``tool-frame`` write them).
WRITTEN_OFFSETS_DEG = [0.0, -1.201831, 1.499818, -1.999015, 1.09977, 0.0]
WRITTEN_STD_DEG = [-1.0, 0.006032, 0.004167, 0.0044, 0.000562, -1.0]
WRITTEN_TOOL_MM = [0.315377, -0.193238, 80.178256]
WRITTEN_TOOL_DEG = [0.202429, -0.218022, 0.0]


def calibrated_profile(
    path: Path, reason: str = "calibrate --method exact: fit ok (χ²ᵣ 0.282)"
) -> Path:
    """Create a tx90l profile at ``path`` and write into it what a calibrate run (history
    write 1, with ``reason``) and a tool-frame run (write 2) write."""
    create_profile(path, "tx90l")
    calibration = {
        "joint_offsets_deg": WRITTEN_OFFSETS_DEG,
        "unobservable_joints": [1, 6],
        "method": "exact",
        "std_deg": WRITTEN_STD_DEG,
        "sound_speed_m_s": 1482.385,
        "fit_verdict": "ok",
        "chi2_reduced": 0.2822,
        "date": "2026-01-05T09:30:00+00:00",
        "level": "offsets",
        "condition_number": 96.887,
    }
    write_profile(path, {"calibration": calibration}, reason)
    tool = {
        "position_mm": WRITTEN_TOOL_MM,
        "rotation_deg": WRITTEN_TOOL_DEG,
        "position_std_mm": [0.005412, 0.00584, 0.751985],
        "rotation_std_deg": [0.00034, 0.000347, 0.5],
    }
    write_profile(path, {"tool": tool}, "tool-frame (exact)")
    return path


def once_per_run(
    factory: pytest.TempPathFactory, name: str, make: Callable[[Path], dict[str, Any]]
) -> tuple[Path, dict[str, Any]]:
    """``make(directory)``'s JSON result and its directory, made once for the test run: the
    xdist workers share the run's temporary root, and the first to ask makes it there (the
    others wait on a lock, then read it), where a module- or session-scoped fixture is made
    again by every worker that runs one of its tests. Alone (no xdist, or no ``fcntl``) the
    run makes it itself. The directory is the makers' to write: a test that writes copies it.
    """
    if os.environ.get("PYTEST_XDIST_WORKER") is None or fcntl is None:
        directory = factory.mktemp(name)
        return directory, make(directory)
    directory = factory.getbasetemp().parent / name
    done = directory.with_name(f"{name}.json")
    with open(directory.with_name(f"{name}.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(directory, ignore_errors=True)
            directory.mkdir()
            result = make(directory)
            done.write_text(json.dumps(result), encoding="utf-8")
    return directory, json.loads(done.read_text(encoding="utf-8"))


def exit_code(args: list[str]) -> int:
    """Exit code of ``ucal ARGS`` run in this process (output goes to pytest's capture). The
    root logger's level is put back after: ``-q`` sets ERROR, and a later test's warnings would
    not reach its log capture."""
    root = logging.getLogger()
    level = root.level
    try:
        main(args)
    except SystemExit as e:
        return 0 if e.code is None else int(e.code)
    finally:
        root.setLevel(level)
    return 0


def ucal_here(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``ucal ARGS`` run in this process as ``python -m ucal`` would run it: its exit code and
    what it wrote to stdout and stderr (the same command-line code, without a new
    interpreter's imports: for commands whose separate process is not what is tested). Its
    log lines (warnings) go to pytest's log capture, which holds the root logger: a test that
    reads one runs a process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.ExitStack() as stack:
        stack.enter_context(contextlib.redirect_stdout(out))
        stack.enter_context(contextlib.redirect_stderr(err))
        if cwd is not None:
            stack.enter_context(contextlib.chdir(cwd))
        code = exit_code(list(args))
    return subprocess.CompletedProcess(["ucal", *args], code, out.getvalue(), err.getvalue())


@contextlib.contextmanager
def terminal_typed(text: str) -> Iterator[TextIO]:
    """A terminal on which the user has typed ``text``, for stdin."""
    master, slave = os.openpty()
    try:
        os.write(master, text.encode())
        with open(slave, encoding="utf-8") as tty:
            yield tty
    finally:
        os.close(master)


def crc16_modbus(data: bytes) -> bytes:
    """Reference CRC-16/MODBUS, bit by bit (poly 0xA001 reflected, init 0xFFFF), low byte first."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


class ScriptedPort:
    """A serial port double: a dialogue of (expected request, reply or None) pairs.

    Every write must equal the next expected request; its reply then becomes readable.
    :meth:`assert_done` fails if a pair is left unused or bytes are left unread.
    """

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]]):
        self.dialogue = list(dialogue)
        self.rx = bytearray()
        self.is_open = True
        self.inter_byte_timeout: float | None = None

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def write(self, data: bytes) -> int:
        assert self.dialogue, f"unexpected write {bytes(data).hex(' ')}"
        expected, reply = self.dialogue.pop(0)
        assert bytes(data) == expected, f"sent {bytes(data).hex(' ')}, expected {expected.hex(' ')}"
        self.rx += reply or b""
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    def close(self) -> None:
        self.is_open = False

    def assert_done(self) -> None:
        assert not self.dialogue, f"unused pairs: {self.dialogue}"
        assert not self.rx, f"unread bytes: {bytes(self.rx).hex(' ')}"


class ScriptedVisaResource:
    """A PyVISA message-based resource double (``write_raw``, ``read_raw``, ``read_bytes``,
    ``timeout``, ``close``): a dialogue of (expected message, reply or None) pairs.

    Every ``write_raw`` must equal the next expected message; its reply then becomes readable.
    A read with nothing left raises PyVISA's timeout error, as the resource would.
    :meth:`assert_done` fails if a pair is left unused or bytes are left unread.
    """

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]]):
        self.dialogue = list(dialogue)
        self.rx = bytearray()
        self.timeout = 2000.0
        self.closed = False

    def write_raw(self, data: bytes) -> int:
        assert self.dialogue, f"unexpected write {bytes(data)!r}"
        expected, reply = self.dialogue.pop(0)
        assert bytes(data) == expected, f"sent {bytes(data)!r}, expected {expected!r}"
        self.rx += reply or b""
        return len(data)

    def _timeout(self) -> Exception:
        from pyvisa import constants, errors

        return errors.VisaIOError(constants.StatusCode.error_timeout)

    def read_raw(self) -> bytes:
        end = self.rx.find(b"\n")
        if end < 0:
            raise self._timeout()
        out = bytes(self.rx[: end + 1])
        del self.rx[: end + 1]
        return out

    def read_bytes(self, count: int, break_on_termchar: bool = False) -> bytes:
        if len(self.rx) < count:
            raise self._timeout()
        out = bytes(self.rx[:count])
        del self.rx[:count]
        return out

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.dialogue, f"unused pairs: {self.dialogue}"
        assert not self.rx, f"unread bytes: {bytes(self.rx)!r}"


class QuietPulser(PulserReceiver):
    """A pulser-receiver at ``endpoint`` that takes every setting and reports the defaults;
    :meth:`read_gate` is the subclass's."""

    def __init__(self, endpoint: str):
        self._endpoint = endpoint

    @property
    def endpoint(self) -> str:
        return self._endpoint

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def configure(self, settings: PulserSettings) -> None:
        pass

    def settings(self) -> PulserSettings:
        return PulserSettings()

    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        raise NotImplementedError


class FakeController(RobotController):
    """Moves at once; always at rest, powered, no error. ``q`` is where the arm is (deg),
    ``moves`` how many targets it was sent."""

    def __init__(self, q: np.ndarray | None = None) -> None:
        self.q = np.zeros(6) if q is None else np.asarray(q, float).copy()
        self.moves = 0

    @property
    def endpoint(self) -> str:
        return "fake-controller://bench"

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def read_joints(self, timeout_s: float = 2.0) -> np.ndarray:
        return self.q.copy()

    def status(self, timeout_s: float = 2.0) -> ControllerStatus:
        return ControllerStatus(True, False, False, False)

    def start_move(self, target_deg: np.ndarray, speed: float = 0.5) -> None:
        self.moves += 1
        self.q = np.asarray(target_deg, float).copy()

    def wait_settled(
        self, target_deg: np.ndarray, timeout_s: float, tol_deg: float = 1e-3
    ) -> np.ndarray:
        return self.q.copy()

    def stop(self) -> None:
        pass

    def joint_samples(self, since_t_s: float = 0.0) -> list[JointSample]:
        return []


def measured_cell(profile, plan, model, offsets, block_rpy, corner, water_c, seed, sigma):
    """Measurements of the true cell (``model``, ``offsets``, the block at ``corner`` turned by
    ``block_rpy``, water at ``water_c``) at ``plan``'s postures: the wrist aimed at normal
    incidence and the water path along the normal, each with seeded noise of ``sigma`` (deg of
    posture, mm of path)."""
    rng = np.random.default_rng(seed)
    truth = CellGeometry(model, profile.tool_matrix, rpy_to_matrix(block_rpy))
    postures = []
    for p in plan.postures:
        q = aim_wrist(truth, p.joints_deg, -truth.normal(p.face), offsets)
        q[3:5] += rng.normal(0.0, sigma, 2)
        postures.append((p.label, p.face, q))
    scale = sound_speed_m_s(profile.water_temperature_c) / sound_speed_m_s(water_c)
    return [
        FaceMeasurement(
            m.config, m.face, m.joints_deg, m.distance_mm + rng.normal(0.0, sigma), sigma, sigma
        )
        for m in ideal_measurements(truth, corner, postures, offsets, path_scale=scale)
    ]


def noisy_world(*, served_at_a_tenth: bool = False, **pulser: object) -> str:
    """A world file's text: the demo cell's joint offsets and noise (``ucal.sim.demo``), and
    the ``[pulser]`` keys given (strings quoted). ``served_at_a_tenth``: the state stream's
    period, latency and jitter a tenth of the released server's (2, 0.2, 0.1 ms), for a cell
    served at ``--time-scale 0.1``, whose moves and acquisitions are ten times faster: the
    settle waits, one or two frames each, stay in proportion to the moves they end."""
    from ucal.sim.demo import DEMO_JOINT_OFFSETS_DEG, DEMO_NOISE

    keys = "".join(f"{k} = {json.dumps(v)}\n" for k, v in pulser.items())
    timing = (
        "[timing]\nstate_period_ms = 2.0\nstate_latency_ms = 0.2\nstate_jitter_ms = 0.1\n"
        if served_at_a_tenth
        else ""
    )
    return (
        f"[robot]\njoint_offsets_deg = {DEMO_JOINT_OFFSETS_DEG.tolist()}\n"
        f"[noise]\ntof_ns = {DEMO_NOISE.tof_ns}\namplitude = {DEMO_NOISE.amplitude}\n"
        f"seed = {DEMO_NOISE.seed}\n{timing}[pulser]\n{keys}"
    )


def finished_json(proc: subprocess.Popen[str]) -> dict:
    """A ``ucal ... --json`` process waited for: it exits 0; its JSON object."""
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    return json.loads(out)


def std_of(result: dict) -> np.ndarray:
    """``std_deg`` of a result (6,), NaN where a joint was not determined."""
    return np.array([np.nan if v is None else v for v in result["std_deg"]])


def noisy_face(
    truth: CellGeometry,
    config: str,
    face: int,
    arm_deg: np.ndarray,
    offsets_deg: np.ndarray,
    corner_mm: np.ndarray,
    rng: np.random.Generator,
    tilt_std_deg: float,
    distance_std_mm: float,
    path_scale: float = 1.0,
    **fields: object,
) -> FaceMeasurement:
    """Face ``face`` measured on the true cell from arm ``arm_deg``: the wrist aimed at normal
    incidence with ``offsets_deg``, its two wrist readings off by ``tilt_std_deg`` of noise;
    the water path along the normal, times ``path_scale`` (assumed over true sound speed),
    off by ``distance_std_mm``; ``fields``: the measurement's other fields."""
    q = aim_wrist(truth, arm_deg, -truth.normal(face), offsets_deg)
    _, tcp = beam_and_tcp(truth, q, offsets_deg)
    path = float(truth.normal(face) @ (tcp - corner_mm))
    read = q.copy()
    read[3:5] += rng.normal(0.0, tilt_std_deg, 2)
    noisy = path * path_scale + rng.normal(0.0, distance_std_mm)
    return FaceMeasurement(
        config,
        face,
        read,
        noisy,
        distance_std_mm,
        tilt_std_deg,
        **fields,  # type: ignore[arg-type]
    )


def counting_moves(monkeypatch: Any) -> dict[str, int]:
    """Count the controller motions (``Rig.move``) of the commands run after it, in this
    process: ``{"n": moves}``, what a refusal before the first motion leaves at 0."""
    from ucal.devices.rig import Rig

    moves = {"n": 0}
    move = Rig.move

    def counted(self: Rig, q: Any, speed: Any = None) -> Any:
        moves["n"] += 1
        return move(self, q, speed)

    monkeypatch.setattr(Rig, "move", counted)
    return moves


def hand_edited(lines: list[str], values: list[str]) -> Any:
    """A hypothesis strategy of ``lines`` with one to four hand edits: a line pasted twice,
    deleted, its value (after ``=``, or one of its comma-separated cells) replaced by one of
    ``values``, or cut short."""
    from hypothesis import strategies as st

    @st.composite
    def edits(draw: st.DrawFn) -> str:
        out = list(lines)
        value = st.sampled_from(values)
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(out) - 1))
            edit = draw(st.sampled_from(["twice", "delete", "value", "cut"]))
            if edit == "twice":
                out.insert(i, out[i])
            elif edit == "delete" and len(out) > 1:
                del out[i]
            elif edit == "value" and not out[i].lstrip().startswith("#"):
                if "=" in out[i]:
                    out[i] = f"{out[i].split('=', 1)[0]}= {draw(value)}\n"
                elif "," in out[i]:
                    cells = out[i].rstrip("\n").split(",")
                    cells[draw(st.integers(0, len(cells) - 1))] = draw(value)
                    out[i] = ",".join(cells) + "\n"
            elif edit == "cut":
                out[i] = out[i][: draw(st.integers(0, len(out[i])))] + "\n"
        return "".join(out)

    return edits()
