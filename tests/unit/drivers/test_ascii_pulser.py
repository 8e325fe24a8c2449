"""The ASCII serial pulser, byte for byte against a scripted serial port (every pair used,
nothing left unread), and the back-end that pairs it with a digitiser and a host echo timer."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from drivers.digitizer.base import AScanRecord, Digitizer, EchoTiming
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser import ascii_commands as cmd
from drivers.pulser.ascii import AsciiPulser, AsciiScpiPulser
from drivers.pulser.base import PulserSettings
from drivers.pulser.urls import parse_ascii_url
from drivers.registry import open_pulser
from drivers.urls import UrlError

from doubles import ScriptedPort

URL = "ascii://socket://127.0.0.1:5000"
SCOPE = "visa://TCPIP::127.0.0.1::5025::SOCKET"
HELLO = (b"G?\r", b"G=200\r")


def set_pair(letter: str, code: int) -> list[tuple[bytes, bytes | None]]:
    """A command and the query that reads it back, the device having taken it."""
    return [
        (f"{letter}{code}\r".encode(), None),
        (f"{letter}?\r".encode(), f"{letter}={code}\r".encode()),
    ]


class FakeDigitizer(Digitizer):
    """A digitiser that keeps what it was asked and hands out the records it holds."""

    def __init__(self, records: list[AScanRecord] | None = None):
        self.windows: list[tuple[float, float, int]] = []
        self.records = list(records or [])
        self.waits: list[tuple[float | None, float]] = []  # (timeout_s, acquisition_s) asked

    @property
    def endpoint(self) -> str:
        return SCOPE

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        self.windows.append((start_ns, width_ns, averages))

    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        self.waits.append((timeout_s, acquisition_s))
        return self.records.pop(0)


def back_end(
    *dialogue: tuple[bytes, bytes | None], digitizer: Digitizer | None = None, **options
) -> tuple[AsciiScpiPulser, ScriptedPort]:
    port = ScriptedPort([HELLO, *dialogue])
    pulser = AsciiScpiPulser(URL, digitizer or FakeDigitizer(), 0.05, port=port, **options)
    pulser.connect()
    return pulser, port


# --- the command set ------------------------------------------------------------------------


def test_commands_queries_and_answers_are_a_letter_a_number_and_cr() -> None:
    assert cmd.command(cmd.Letter.GAIN, 372) == b"G372\r"
    assert cmd.command(cmd.Letter.GAIN, -120) == b"G-120\r"
    assert cmd.query(cmd.Letter.LOW_PASS) == b"L?\r"
    assert cmd.answer(cmd.Letter.PRF, 100) == b"P=100\r"
    assert cmd.parse_answer(cmd.Letter.GAIN, b"G=372\r") == 372
    for wrong in (b"P=372\r", b"G372\r", b"G=\r", b"G=3.5\r"):
        with pytest.raises(ValueError, match="expected 'G=<n>'"):
            cmd.parse_answer(cmd.Letter.GAIN, wrong)
    assert cmd.parse_line(b"v300\r") == (cmd.Letter.VOLTAGE, 300)
    assert cmd.parse_line(b"D?") == (cmd.Letter.DAMPING, None)
    assert cmd.parse_line(b"X1\r") is None and cmd.parse_line(b"Gx\r") is None


def test_knobs_take_the_devices_own_steps_and_refuse_what_it_cannot_do() -> None:
    gain, prf = cmd.KNOBS[cmd.Letter.GAIN], cmd.KNOBS[cmd.Letter.PRF]
    assert gain.code(37.26) == 373 and gain.value(373) == pytest.approx(37.3)
    assert prf.code(1000.0) == 100 and prf.code(4996.0) == 500
    damping, low_pass = cmd.KNOBS[cmd.Letter.DAMPING], cmd.KNOBS[cmd.Letter.LOW_PASS]
    assert [damping.code(r) for r in (40.0, 60.0, 75.0, 700.0)] == [0, 0, 1, 3]
    assert low_pass.code(50.0) == 2 and low_pass.value(2) == 48.0  # L2 = 48 MHz
    for knob, asked, message in (
        (gain, 84.1, r"gain_db = 84.1 dB is outside .*\(-12 … 84 dB, in steps of 0.1 dB\)"),
        (prf, 6000.0, "prf_hz"),
        (damping, 1000.0, r"damping_ohm = 1000 Ω is outside .*\(50, 100, 200, 500 Ω\)"),
        (gain, math.nan, "finite"),
    ):
        with pytest.raises(ValueError, match=message):
            knob.code(asked)


def test_ascii_urls() -> None:
    assert parse_ascii_url(URL).device == "socket://127.0.0.1:5000"
    assert parse_ascii_url("ascii:///dev/ttyUSB0?baud=19200").baud == 19200
    assert str(parse_ascii_url("ascii://COM3?baud=9600")) == "ascii://COM3"
    for bad in ("ascii://", "ascii://COM3?baud=fast", "ascii://COM3?unit=1", "modbus-rtu://COM3"):
        with pytest.raises(UrlError):
            parse_ascii_url(bad)


def test_the_scheme_opens_the_back_end_which_needs_its_digitiser() -> None:
    pulser = open_pulser(URL, digitizer=SCOPE)
    assert isinstance(pulser, AsciiScpiPulser) and pulser.digitizer.endpoint == SCOPE
    with pytest.raises(ValueError, match="does not digitise: give its digitiser, --digitizer"):
        open_pulser(URL)


# --- the serial line ------------------------------------------------------------------------


def test_connect_asks_the_gain_to_know_a_pulser_answers() -> None:
    port = ScriptedPort([HELLO])
    line = AsciiPulser(URL, 0.05, port=port)
    line.connect()
    port.assert_done()


@pytest.mark.parametrize(
    "reply, error, message",
    [
        (None, DeviceTimeout, r"pulser at ascii://socket://127.0.0.1:5000: read G: no answer"),
        (b"?\r", ProtocolError, r"read G: expected 'G=<n>', got '\?'"),
        (b"P=200\r", ProtocolError, "got 'P=200'"),
    ],
)
def test_a_missing_or_wrong_answer_names_the_pulser(
    reply: bytes | None, error: type[Exception], message: str
) -> None:
    port = ScriptedPort([(b"G?\r", reply)])
    with pytest.raises(error, match=message):
        AsciiPulser(URL, 0.05, port=port).connect()
    port.assert_done()


def test_bytes_nobody_asked_for_are_dropped_before_a_query() -> None:
    port = ScriptedPort([HELLO, (b"G373\r", b"G=373\r"), (b"G?\r", b"G=373\r")])
    line = AsciiPulser(URL, 0.05, port=port)
    line.connect()
    assert line.set(cmd.Letter.GAIN, 373) == 373  # the echo of the command is not the answer
    port.assert_done()


# --- the back-end ---------------------------------------------------------------------------


def test_configure_sets_each_knob_to_the_devices_step_reads_it_back_and_records_both() -> None:
    digitizer = FakeDigitizer()
    pulser, port = back_end(
        *set_pair("G", 372),
        *set_pair("P", 100),
        *set_pair("V", 100),
        *set_pair("D", 0),
        *set_pair("L", 2),
        *set_pair("W", 20),
        *set_pair("G", 400),
        digitizer=digitizer,
        pulse_width_ns=20.0,
    )
    settings = PulserSettings(gain_db=37.24, gate_start_us=5.0, gate_width_us=400.0, averages=8)
    returned = pulser.configure(settings)  # what a run's record keeps of the call
    assert digitizer.windows == [(5000.0, 400_000.0, 8)]
    applied = pulser.settings_applied
    assert returned == applied
    assert applied["gain_db"] == {"asked": 37.24, "set": pytest.approx(37.2)}
    assert applied["low_pass_mhz"] == {"asked": 50.0, "set": 48.0}
    assert applied["pulse_width_ns"] == {"asked": 20.0, "set": 20.0}
    assert applied["averages"] == {"asked": 8.0, "set": 8.0}
    pulser.configure(replace(settings, gain_db=40.0))  # only the gain is written again
    port.assert_done()


def test_what_the_devices_cannot_take_is_refused_before_anything_is_written() -> None:
    digitizer = FakeDigitizer()
    pulser, port = back_end(digitizer=digitizer)
    for settings, message in (
        (PulserSettings(gain_db=90.0), "gain_db = 90 dB is outside"),
        (PulserSettings(low_pass_mhz=500.0), "low_pass_mhz = 500 MHz"),
        (PulserSettings(high_pass_mhz=2.0), "high-pass is fixed at 1 MHz"),
        (PulserSettings(prf_hz=5000.0, gate_width_us=400.0), "ends after the pulse repetition"),
    ):
        for call in (pulser.check_settings, pulser.configure):
            with pytest.raises(ValueError, match=message):
                call(settings)
    assert digitizer.windows == []
    port.assert_done()


def test_averages_the_scope_cannot_take_are_refused_by_the_check_with_nothing_sent() -> None:
    """What a run checks before its first motion: the scope's own average counts."""

    class RefusingDigitizer(FakeDigitizer):
        def check(self, start_ns: float, width_ns: float, averages: int) -> None:
            if averages > 4096:
                raise ValueError(f"digitizer: averages must be 1 … 4096, got {averages}")

    digitizer = RefusingDigitizer()
    pulser, port = back_end(digitizer=digitizer)
    pulser.check_settings(PulserSettings(averages=4096))
    with pytest.raises(ValueError, match="averages must be 1 … 4096, got 5000"):
        pulser.check_settings(PulserSettings(averages=5000))
    assert digitizer.windows == []
    port.assert_done()


def test_a_pulser_that_sets_another_value_than_written_is_a_device_error() -> None:
    pulser, port = back_end((b"G372\r", None), (b"G?\r", b"G=200\r"))
    with pytest.raises(DeviceError, match=r"wrote G372 \(37.2 dB\), the pulser set G=200"):
        pulser.configure(PulserSettings(gain_db=37.2))
    port.assert_done()


def test_settings_are_read_back_from_the_pulser() -> None:
    pulser, port = back_end(
        (b"G?\r", b"G=372\r"),
        (b"P?\r", b"P=50\r"),
        (b"V?\r", b"V=300\r"),
        (b"D?\r", b"D=3\r"),
        (b"L?\r", b"L=1\r"),
    )
    got = pulser.settings()
    port.assert_done()
    assert (got.gain_db, got.prf_hz, got.pulse_voltage_v) == (pytest.approx(37.2), 500.0, 300.0)
    assert (got.damping_ohm, got.low_pass_mhz, got.high_pass_mhz) == (500.0, 24.0, 1.0)


def record(volts: list[float], counter: int = 1) -> AScanRecord:
    return AScanRecord(5000.0, 5.0, np.array(volts), (-1.0, 1.0), 1e-3, False, 1, counter, 0.0)


def test_a_reading_is_the_host_timers_echo_in_full_screen_units_above_the_threshold() -> None:
    seen: list[tuple[AScanRecord, tuple[float, float]]] = []

    def timer(rec: AScanRecord, gate: tuple[float, float]) -> EchoTiming:
        seen.append((rec, gate))
        k = int(np.argmax(np.abs(rec.samples)))
        return EchoTiming(float(abs(rec.samples[k])), rec.t0_ns + k * rec.dt_ns, 0.1, "test")

    digitizer = FakeDigitizer([record([0.0, 0.25, 0.0], 7), record([0.005, 0.0, 0.0], 8)])
    pulser, port = back_end(digitizer=digitizer, full_screen_v=0.5)
    with pytest.raises(RuntimeError, match="no echo timer"):
        pulser.read_gate()
    pulser.echo_timer = timer
    echo = pulser.read_gate()
    assert (echo.amplitude, echo.tof_ns, echo.counter) == (0.5, 5005.0, 7)
    assert seen[0][1] == (5000.0, 205_000.0)  # the gate of the default settings
    assert seen[0][0].rails == (-2.0, 2.0)  # volts → fractions of full screen
    weak = pulser.read_gate()  # 0.01 of full screen: below the 0.02 threshold
    assert weak.amplitude == pytest.approx(0.01) and math.isnan(weak.tof_ns)
    port.assert_done()


def test_the_scope_may_take_its_averages_at_the_pulsers_prf_beyond_the_link_timeout() -> None:
    """1,000 averages at 500 Hz: 2 s of averaging for the scope's completion, then the link's
    0.05 s; the deadline follows what was configured."""
    digitizer = FakeDigitizer([record([0.0, 0.25, 0.0])])
    pulser, port = back_end(
        *set_pair("G", 200),
        *set_pair("P", 50),
        *set_pair("V", 100),
        *set_pair("D", 0),
        *set_pair("L", 2),
        digitizer=digitizer,
        echo_timer=lambda rec, gate: EchoTiming(0.5, 5005.0, 0.1, "test"),
    )
    assert pulser.reading_wait().total_s == pytest.approx(0.001 + 0.05)  # before configure
    pulser.configure(PulserSettings(prf_hz=500.0, averages=1000))
    wait = pulser.reading_wait()
    assert (wait.acquisition_s, wait.transfer_s, wait.link_s) == (2.0, 0.0, 0.05)
    assert wait.total_s == pytest.approx(2.05)
    assert pulser.read_gate().has_echo
    assert digitizer.waits == [(0.05, 2.0)]  # the link's margin, and the averaging beyond it
    port.assert_done()
