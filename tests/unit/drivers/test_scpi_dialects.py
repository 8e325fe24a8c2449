"""Each family's dialect, chosen by ``*IDN?``, and the Rigol DS1000Z's dialogues byte for byte:
one command a message, the trigger on CH2 set and read back, the 1-2-5 time base, averages in
powers of two, the single sweep polled until it stops, the preamble in its own codes (the
origin in codes, the type its read mode) and the window's points read by parts."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.digitizer import scpi
from drivers.digitizer.dialects import KEYSIGHT, RIGOL, dialect_of
from drivers.digitizer.visa import ScpiScope
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

from doubles import ScriptedVisaResource

URL = "visa://TCPIP::192.168.0.9::5555::SOCKET"
IDN = (b"*IDN?\n", b"RIGOL TECHNOLOGIES,DS1104Z,DS1ZA000000001,00.04.04.SP3\n")
OK = b'0,"No error"\n'
SET_UP = [
    (b"*CLS\n", None),
    (b":WAV:SOUR CHAN1\n", None),
    (b":WAV:MODE RAW\n", None),
    (b":WAV:FORM BYTE\n", None),
    (b":CHAN1:SCAL 2.500000E-01\n", None),  # 1 V full screen: 4 of the 8 divisions
    (b":CHAN1:OFFS 0\n", None),
    (b":TRIG:MODE EDGE\n", None),
    (b":TRIG:SWE NORM\n", None),
    (b":TRIG:EDG:SOUR CHAN2\n", None),
    (b":TRIG:EDG:LEV 1.400000E+00\n", None),
    (b":TRIG:EDG:SLOP POS\n", None),
    (b":TRIG:SWE?\n", b"NORM\n"),
    (b":TRIG:EDG:SOUR?\n", b"CHAN2\n"),
    (b":TRIG:EDG:LEV?\n", b"1.400000e+00\n"),
    (b":SYST:ERR?\n", OK),
]
# a 40 ns window from 5 µs: 5 ns a division (12 divisions hold 60 ns), the centre 30 ns on
CONFIGURE_16 = [
    (b":TIM:MAIN:SCAL 5.000000E-09\n", None),
    (b":TIM:MAIN:OFFS 5.030000E-06\n", None),
    (b":ACQ:TYPE AVER\n", None),
    (b":ACQ:AVER 16\n", None),
    (b":SYST:ERR?\n", OK),
]
# BYTE, RAW, 61 points, 16 averages, 1 ns from 5 µs; 10 mV a code, yorigin −3 codes, yref 127
PREAMBLE = (
    b":WAV:PRE?\n",
    b"0,2,61,16,1.000000e-09,5.000000e-06,0,1.000000e-02,-3,127\n",
)
CODES = np.arange(41) + 100  # the window's 41 points (0 … 40 ns)


def scope(
    *dialogue: tuple[bytes, bytes | None], url: str = URL
) -> tuple[ScpiScope, ScriptedVisaResource]:
    resource = ScriptedVisaResource([IDN, *SET_UP, *dialogue])
    device = ScpiScope(url, 0.5, resource=resource)
    device.connect()
    return device, resource


def single(*states: str) -> list[tuple[bytes, bytes | None]]:
    """``:SING``, then the status polled, answering ``states``."""
    return [(b":SING\n", None)] + [(b":TRIG:STAT?\n", s.encode() + b"\n") for s in states]


def data(first: int, last: int, codes: np.ndarray) -> list[tuple[bytes, bytes | None]]:
    return [
        (f":WAV:STAR {first}\n".encode(), None),
        (f":WAV:STOP {last}\n".encode(), None),
        (b":WAV:DATA?\n", scpi.format_block(codes.astype("u1").tobytes(), 9) + b"\n"),
    ]


# --- which family ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "idn, family",
    [
        ("KEYSIGHT TECHNOLOGIES,DSOX3024T,MY1,07.50", "keysight"),
        ("AGILENT TECHNOLOGIES,DSO-X 2024A,MY1,02.43", "keysight"),
        ("KEYSIGHT TECHNOLOGIES,MSOX3104T,MY1,07.50", "keysight"),
        ("RIGOL TECHNOLOGIES,DS1054Z,DS1ZA1,00.04.04", "rigol"),
        ("RIGOL TECHNOLOGIES,DS1074Z Plus,DS1ZC1,00.04.05", "rigol"),
        ("Rigol Technologies,MSO1104Z-S,DS1ZB1,00.04.04", "rigol"),
        ("RIGOL TECHNOLOGIES,DS2072A,DS2A1,00.03.06", None),  # another guide's family
        ("KEYSIGHT TECHNOLOGIES,DSOX1102G,CN1,02.12", None),  # the 1000 X-Series' own guide
        ("TEKTRONIX,MDO3024,C1,CF:91.1CT", None),
    ],
)
def test_the_family_is_chosen_by_manufacturer_and_model(idn: str, family: str | None) -> None:
    found = dialect_of(scpi.parse_idn(idn))
    assert (found.family if found else None) == family


def test_the_families_do_not_share_their_preamble_codes() -> None:
    # format 2 is a Rigol's ASCii and no Keysight code; type 2 is a Keysight's AVERage and a
    # Rigol's RAW read mode; a Rigol's y origin is in codes, a Keysight's in volts
    assert (KEYSIGHT.formats[4], RIGOL.formats[2]) == ("ASCII", "ASCII")
    assert 2 not in KEYSIGHT.formats and 4 not in RIGOL.formats
    assert (KEYSIGHT.types[2], RIGOL.types[2]) == ("AVERAGE", "RAW")
    p = RIGOL.preamble(PREAMBLE[1].decode())
    assert (p.format, p.type, RIGOL.averaged(p)) == ("BYTE", "RAW", 16)
    np.testing.assert_allclose(p.volts(np.array([124, 130])), [-0.0, 0.06], atol=1e-12)
    assert p.t0_ns == pytest.approx(5000.0) and p.dt_ns == pytest.approx(1.0)


def test_the_rigol_time_base_is_a_1_2_5_step_whose_12_divisions_hold_the_window() -> None:
    assert RIGOL.window(5e-6, 50e-6) == (
        (":TIM:MAIN:SCAL", "5.000000E-06"),  # 50/12 = 4.17 µs: 5 µs a division
        (":TIM:MAIN:OFFS", "3.500000E-05"),  # the centre 30 µs after the start
    )
    assert RIGOL.window(0.0, 240e-6)[0] == (":TIM:MAIN:SCAL", "2.000000E-05")
    with pytest.raises(ValueError, match="cannot hold"):
        RIGOL.window(0.0, 1000.0)


@pytest.mark.parametrize("averages", [3, 12, 2048])
def test_a_rigol_averages_powers_of_two_only(averages: int) -> None:
    with pytest.raises(ValueError, match="power of two"):
        RIGOL.check_averages(averages)
    KEYSIGHT.check_averages(12)  # a Keysight takes any count 2 … 65536


# --- the Rigol's dialogues ------------------------------------------------------------------


def test_connect_sets_the_rigol_up_one_command_a_message_its_trigger_on_ch2() -> None:
    device, resource = scope()
    resource.assert_done()
    identity = device.identity()
    assert identity["family"] == "rigol" and identity["model"] == "DS1104Z"
    assert identity["trigger"] == {"source": "CHAN2", "level_v": 1.4, "sweep": "NORM"}


def test_a_rigol_has_no_ext_trigger_input() -> None:
    resource = ScriptedVisaResource([IDN])
    device = ScpiScope(URL + "?trigger=EXT", 0.5, resource=resource)
    with pytest.raises(DeviceError, match=r"edge trigger takes CHAN2, CHAN3, CHAN4 .*not EXT"):
        device.connect()
    resource.assert_done()


def test_a_rigol_refuses_a_count_before_anything_is_written_once_connected() -> None:
    device, resource = scope()
    with pytest.raises(ValueError, match="a power of two of acquisitions, 2 … 1024, got 12"):
        device.configure(5000.0, 40.0, 12)
    resource.assert_done()


def test_one_rigol_acquisition_is_single_polled_preamble_and_the_windows_points() -> None:
    device, resource = scope(
        *CONFIGURE_16,
        *single("STOP", "WAIT", "WAIT", "TD", "STOP"),  # the last one's STOP, then its own
        PREAMBLE,
        *data(1, 41, CODES),
    )
    device.configure(5000.0, 40.0, 16)
    # a STOP before the scope said it was armed is the last record's, however fast the host:
    # the acquisition's own time (10 s) has not passed
    record = device.acquire(timeout_s=0.5, acquisition_s=10.0)
    resource.assert_done()
    assert record.t0_ns == pytest.approx(5000.0) and record.dt_ns == pytest.approx(1.0)
    assert record.n == 41 and (record.averages, record.counter) == (16, 1)
    # (code − yorigin − yreference)·yincrement: the origin in codes
    np.testing.assert_allclose(record.samples, (CODES + 3 - 127) * 0.01)
    assert record.rails == pytest.approx(((0 + 3 - 127) * 0.01, (255 + 3 - 127) * 0.01))
    assert record.lsb == pytest.approx(0.01) and not record.clipped


def test_the_rigol_reads_the_window_late_in_its_record_and_only_what_changed() -> None:
    late = (PREAMBLE[0], b"0,2,61,16,1.000000e-09,4.990000e-06,0,1.000000e-02,0,127\n")
    device, resource = scope(
        *CONFIGURE_16,
        *single("TD", "STOP"),
        late,
        *data(11, 51, CODES),  # the window starts 10 ns into the record
        *single("TD", "STOP"),
        late,
        (b":WAV:DATA?\n", scpi.format_block(CODES.astype("u1").tobytes(), 9) + b"\n"),
    )
    device.configure(5000.0, 40.0, 16)
    assert device.acquire(timeout_s=0.5).t0_ns == pytest.approx(5000.0)
    assert device.acquire(timeout_s=0.5).t0_ns == pytest.approx(5000.0)  # STAR, STOP kept
    resource.assert_done()


def test_a_record_longer_than_one_read_is_read_by_parts() -> None:
    wide = (PREAMBLE[0], b"0,2,600001,1,1.000000e-09,0.000000e+00,0,1.000000e-02,0,127\n")
    codes = np.full(600_001, 127)
    device, resource = scope(
        (b":TIM:MAIN:SCAL 5.000000E-05\n", None),
        (b":TIM:MAIN:OFFS 3.000000E-04\n", None),
        (b":ACQ:TYPE NORM\n", None),
        (b":SYST:ERR?\n", OK),
        *single("TD", "STOP"),
        wide,
        *data(1, 250_000, codes[:250_000]),
        *data(250_001, 500_000, codes[:250_000]),
        *data(500_001, 600_001, codes[:100_001]),
    )
    device.configure(0.0, 600_000.0, 1)
    assert device.acquire(timeout_s=0.5).n == 600_001
    resource.assert_done()


def test_a_rigol_that_runs_untriggered_is_refused() -> None:
    device, resource = scope(*single("AUTO"))
    with pytest.raises(DeviceError, match=r"runs untriggered \(:TRIG:STAT\? answered AUTO\)"):
        device.acquire(timeout_s=0.5)
    resource.assert_done()


def test_a_rigol_preamble_that_is_not_the_memory_is_refused() -> None:
    screen = (PREAMBLE[0], b"0,0,1200,1,5.000000e-11,5.000000e-06,0,1.000000e-02,0,127\n")
    device, resource = scope(*single("TD", "STOP"), screen)
    with pytest.raises(ProtocolError, match="preamble type NORMAL: the record is read in RAW"):
        device.acquire(timeout_s=0.5)
    resource.assert_done()


class WaitingResource(ScriptedVisaResource):
    """The scripted resource whose status query, once the dialogue is done, answers WAIT."""

    def write_raw(self, data: bytes) -> int:
        if not self.dialogue and bytes(data) == b":TRIG:STAT?\n":
            self.rx += b"WAIT\n"
            return len(data)
        return super().write_raw(data)


def test_a_rigol_that_does_not_trigger_is_a_timeout_naming_the_trigger() -> None:
    resource = WaitingResource([IDN, *SET_UP, (b":SING\n", None)])
    device = ScpiScope(URL, 0.5, resource=resource)
    device.connect()
    with pytest.raises(DeviceTimeout) as info:
        device.acquire(timeout_s=0.02, acquisition_s=0.001)
    resource.assert_done()
    message = str(info.value)
    assert "acquire: no record within" in message and "(0.001 s of it for the" in message
    assert message.endswith(
        "no trigger on CHAN2 rising through 1.4 V (sweep NORM)? Is the pulser's sync output "
        "wired there, and pulsing?"
    )
    assert resource.closed
