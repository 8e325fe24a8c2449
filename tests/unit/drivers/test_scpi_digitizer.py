"""The SCPI oscilloscope client with a Keysight InfiniiVision, byte for byte: IEEE 488.2 blocks,
the preamble's numbers, and the dialogues of connect (the trigger set and read back), configure
and acquire (the trigger event checked) against a scripted VISA resource (every pair used,
nothing left unread)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from drivers.digitizer import scpi
from drivers.digitizer.dialects import KEYSIGHT
from drivers.digitizer.urls import parse_digitizer_url
from drivers.digitizer.visa import ScpiScope
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.urls import UrlError

from doubles import ScriptedVisaResource

URL = "visa://TCPIP::127.0.0.1::5025::SOCKET"
IDN = (b"*IDN?\n", b"KEYSIGHT TECHNOLOGIES,DSOX3024T,MY12345678,07.50\n")
SET_UP = (
    b"*CLS;:WAV:SOUR CHAN1;:WAV:FORM WORD;:WAV:BYT MSBF;:WAV:UNS 1;:WAV:POIN:MODE RAW;"
    b":WAV:POIN MAX;:TIM:REF LEFT;:CHAN1:RANG 2.000000E+00;:CHAN1:OFFS 0;"
    b":TRIG:MODE EDGE;:TRIG:SWE NORM;:TRIG:EDGE:SOUR EXT;:TRIG:EDGE:LEV 1.400000E+00;"
    b":TRIG:EDGE:SLOP POS;:TRIG:SWE?;:TRIG:EDGE:SOUR?;:TRIG:EDGE:LEV?;:SYST:ERR?\n"
)
SETUP = (SET_UP, b'NORM;EXT;+1.40E+00;+0,"No error"\n')
CONFIGURE_8 = (
    b":TIM:RANG 4.000000E-04;:TIM:POS 5.000000E-06;:ACQ:TYPE AVER;:ACQ:COUN 8;:SYST:ERR?\n",
    b'+0,"No error"\n',
)
# the trigger event register read (and so cleared), the acquisition, its completion
ACQUIRE = (b":TER?;:DIG;*OPC?\n", b"+0;1\n")
# WORD, AVERage, 4 points, 8 averages, 5 ns from 5 µs; 2 V over 65536 codes about 0x8000;
# after it the trigger event: 1, a trigger occurred
PREAMBLE_TEXT = b"+1,+2,+4,+8,+5.000000E-09,+5.000000E-06,+0,+3.0517578125E-05,+0.0E+00,+32768"
PREAMBLE = (b":TER?;:WAV:PRE?\n", b"+1;" + PREAMBLE_TEXT + b"\n")
# 0 V, +16 codes, clipped high, -16 codes: a 12-bit ADC left-aligned in 16 bits
DATA = (b":WAV:DATA?\n", b"#9000000008\x80\x00\x80\x10\xff\xff\x7f\xf0\n")
Y_INC = 2.0 / 65536


def scope(*dialogue: tuple[bytes, bytes | None]) -> tuple[ScpiScope, ScriptedVisaResource]:
    resource = ScriptedVisaResource([IDN, SETUP, *dialogue])
    device = ScpiScope(URL, 0.5, resource=resource)
    device.connect()
    return device, resource


# --- framing --------------------------------------------------------------------------------


def test_a_definite_length_block_has_its_digit_its_length_and_its_payload() -> None:
    assert scpi.format_block(b"\x01\x02\x03") == b"#13\x01\x02\x03"
    assert scpi.format_block(b"\x00" * 1000, 9) == b"#9000001000" + b"\x00" * 1000
    payload, rest = scpi.parse_block(b"#9000000004\n\x00\r\xff\nNEXT")
    assert payload == b"\n\x00\r\xff" and rest == b"NEXT"  # LF inside the data is data


def test_a_block_read_through_exact_reads_consumes_its_terminator() -> None:
    stream = bytearray(b"#212" + bytes(range(12)) + b"\n")

    def read_exact(n: int) -> bytes:
        out = bytes(stream[:n])
        del stream[:n]
        return out

    assert scpi.read_block(read_exact) == bytes(range(12))
    assert not stream


@pytest.mark.parametrize(
    "data, message",
    [
        (b"#0\x01\x02\n", "indefinite"),
        (b"#A12\n", "not 1"),
        (b"#3001\x00X", "not followed by LF"),
        (b"#14\x00\x00\n", "announces 4"),
        (b"1,2,3\n", "expected a definite-length block"),
    ],
)
def test_a_malformed_block_is_refused_naming_what_is_wrong(data: bytes, message: str) -> None:
    with pytest.raises(scpi.ScpiError, match=message):
        scpi.parse_block(data)


def test_the_keysight_preamble_gives_the_time_and_volts_of_every_sample() -> None:
    p = KEYSIGHT.preamble(PREAMBLE_TEXT.decode())
    assert (p.format, p.type, p.points, p.count) == ("WORD", "AVERAGE", 4, 8)
    assert KEYSIGHT.averaged(p) == 8
    assert p.t0_ns == pytest.approx(5000.0) and p.dt_ns == pytest.approx(5.0)
    # (code − yreference)·yincrement + yorigin, the origin in volts
    np.testing.assert_allclose(p.volts(np.array([0x8000, 0x8010])), [0.0, 16 * Y_INC])
    with pytest.raises(scpi.ScpiError, match="9 fields"):
        KEYSIGHT.preamble("1,0,4,1,5e-9,0,0,1e-3,0")
    with pytest.raises(scpi.ScpiError, match="xincrement"):
        KEYSIGHT.preamble("1,0,4,1,fast,0,0,1e-3,0,128")


def test_the_keysight_ascii_preamble_is_format_4_and_rigols_ascii_code_is_not_its() -> None:
    # :WAVeform:PREamble: 0 BYTE, 1 WORD, 4 ASCii (a Rigol's ASCii is 2, a code a Keysight
    # never sends: refused, not read as another family's)
    p = KEYSIGHT.preamble("+4,+0,+2,+1,+1.0E-08,+0.0E+00,+0,+3.05E-05,+0.0E+00,+32768")
    assert (p.format, p.type, KEYSIGHT.averaged(p)) == ("ASCII", "NORMAL", 1)
    with pytest.raises(scpi.ScpiError, match="format/type 2/0 is not one the Keysight"):
        KEYSIGHT.preamble("2,0,2,1,1.0E-08,0.0,0,3.05E-05,0.0,32768")


def test_the_adc_step_comes_from_the_codes_trailing_zeros() -> None:
    codes = np.array([0x8000, 0x8010, 0x7FE0, 0xFFFF, 0x0001])
    flags = KEYSIGHT.codes["WORD"].flags  # the clip and hole codes do not count
    assert scpi.code_step(codes, 0x8000, flags) == 16
    assert scpi.code_step(np.array([0x8000] * 4), 0x8000, flags) == 1


def test_digitizer_urls_carry_the_trigger_wiring() -> None:
    assert parse_digitizer_url(URL).resource == "TCPIP::127.0.0.1::5025::SOCKET"
    assert parse_digitizer_url(URL).trigger_source is None
    assert parse_digitizer_url(URL).trigger_level_v == 1.4
    wired = parse_digitizer_url(URL + "?trigger=CHANnel3&level=0.8")
    assert (wired.trigger_source, wired.trigger_level_v) == ("CHAN3", 0.8)
    assert str(wired) == URL + "?trigger=CHAN3&level=0.8"
    assert str(parse_digitizer_url("VISA://USB0::0x0957::0x1796::MY1::INSTR")).startswith(
        "visa://USB0"
    )
    for bad in (
        "visa://",
        "tcp://1.2.3.4:5025",
        "visa://TCPIP::1.2.3.4::SOCKET",
        "scope",
        URL + "?trigger=AUX",
        URL + "?level=high",
        URL + "?level=1e9",
        URL + "?edge=POS",
    ):
        with pytest.raises(UrlError):
            parse_digitizer_url(bad)


# --- dialogues ------------------------------------------------------------------------------


def test_connect_identifies_the_family_sets_the_trigger_up_and_reads_it_back() -> None:
    device, resource = scope()
    assert device.identity() == {
        "manufacturer": "KEYSIGHT TECHNOLOGIES",
        "model": "DSOX3024T",
        "serial": "MY12345678",
        "firmware": "07.50",
        "family": "keysight",
        "trigger": {"source": "EXT", "level_v": 1.4, "sweep": "NORM"},
    }
    resource.assert_done()


def test_the_url_chooses_the_trigger_input_and_level() -> None:
    asked = SET_UP.replace(b"SOUR EXT", b"SOUR CHAN4").replace(
        b"LEV 1.400000E+00", b"LEV 8.000000E-01"
    )
    resource = ScriptedVisaResource([IDN, (asked, b'NORM;CHAN4;+8.0E-01;+0,"No error"\n')])
    device = ScpiScope(URL + "?trigger=CHAN4&level=0.8", 0.5, resource=resource)
    device.connect()
    resource.assert_done()
    assert (device.trigger_source, device.trigger_level_v) == ("CHAN4", 0.8)


@pytest.mark.parametrize(
    "read_back, what",
    [
        (b'AUTO;EXT;+1.40E+00;+0,"No error"\n', "sweep AUTO"),
        (b'NORM;CHAN1;+1.40E+00;+0,"No error"\n', "source CHAN1"),
        (b'NORM;EXT;+8.00E-01;+0,"No error"\n', "level +8.00E-01 V"),
    ],
)
def test_a_trigger_that_reads_back_otherwise_than_set_is_a_device_error(
    read_back: bytes, what: str
) -> None:
    resource = ScriptedVisaResource([IDN, (SET_UP, read_back)])
    device = ScpiScope(URL, 0.5, resource=resource)
    with pytest.raises(
        DeviceError, match=f"the trigger reads back .*{re.escape(what)}.*ucal set EXT"
    ):
        device.connect()
    resource.assert_done()
    assert resource.closed


def test_a_scope_of_no_family_ucal_speaks_is_refused_naming_its_idn() -> None:
    resource = ScriptedVisaResource([(b"*IDN?\n", b"TEKTRONIX,MDO3024,C012345,CF:91.1CT\n")])
    device = ScpiScope(URL, 0.5, resource=resource)
    with pytest.raises(DeviceError) as info:
        device.connect()
    message = str(info.value)
    assert message.startswith(f"digitizer at {URL}: *IDN? answered 'TEKTRONIX,MDO3024,")
    assert "Keysight InfiniiVision 2000/3000 X-Series, Rigol DS1000Z" in message
    resource.assert_done()


def test_configure_writes_what_changed_and_checks_the_error_queue() -> None:
    device, resource = scope(
        CONFIGURE_8,
        (b":ACQ:TYPE NORM;:SYST:ERR?\n", b'+0,"No error"\n'),
    )
    device.configure(5000.0, 400_000.0, 8)
    device.configure(5000.0, 400_000.0, 8)  # nothing changed: nothing written
    device.configure(5000.0, 400_000.0, 1)
    resource.assert_done()


def test_a_refused_setting_is_a_device_error_naming_the_scope_error() -> None:
    device, resource = scope((CONFIGURE_8[0], b'-222,"Data out of range"\n'))
    with pytest.raises(DeviceError, match='-222 "Data out of range"'):
        device.configure(5000.0, 400_000.0, 8)
    resource.assert_done()


def test_a_window_or_count_the_scope_cannot_take_is_refused_before_any_write() -> None:
    device, resource = scope()
    for start, width, averages in ((0.0, 0.0, 1), (0.0, 1e9, 1), (0.0, 1e3, 0), (0.0, 1e3, 1e6)):
        with pytest.raises(ValueError, match="digitizer"):
            device.configure(start, width, averages)  # type: ignore[arg-type]
    resource.assert_done()


def test_one_acquisition_is_dig_opc_the_trigger_event_preamble_and_data() -> None:
    device, resource = scope(CONFIGURE_8, ACQUIRE, PREAMBLE, DATA)
    device.configure(5000.0, 400_000.0, 8)
    record = device.acquire()
    resource.assert_done()
    assert record.t0_ns == pytest.approx(5000.0) and record.dt_ns == pytest.approx(5.0)
    np.testing.assert_allclose(record.samples, np.array([0, 16, 32767, -16]) * Y_INC)
    assert record.clipped  # 0xFFFF
    assert record.rails == pytest.approx(((1 - 32768) * Y_INC, 32767 * Y_INC))
    assert record.lsb == pytest.approx(16 * Y_INC)
    assert (record.averages, record.counter) == (8, 1)


def test_an_untriggered_record_is_refused() -> None:
    # the trigger event register says no trigger occurred: an AUTO sweep's artificial one
    device, resource = scope(ACQUIRE, (PREAMBLE[0], b"+0;" + PREAMBLE_TEXT + b"\n"))
    with pytest.raises(DeviceError, match=r"arrived untriggered \(:TER\? answered '\+0'"):
        device.acquire()
    resource.assert_done()


@pytest.mark.parametrize(
    "fmt, argument, preamble, data, volts, lsb, rails",
    [
        # BYTE: 0x01 clipped low, the step read from the codes (2)
        (
            "BYTE",
            b"BYTE",
            b"0,0,3,1,1.0E-08,0.0,0,7.8125E-03,0.0,128",
            b"#13\x80\x01\x82",
            np.array([0, -127, 2]) * 7.8125e-3,
            2 * 7.8125e-3,
            (-127 * 7.8125e-3, 127 * 7.8125e-3),
        ),
        # ASCII: format 4, the volts themselves; the rails the channel's range as set, the
        # step the preamble's y increment
        (
            "ASCII",
            b"ASC",
            b"+4,+0,+3,+1,+1.0E-08,+0.0E+00,+0,+3.0517578125E-05,+0.0,+32768",
            b"#241+1.000000E-01,-2.500000E-01,+1.000000E+00",
            np.array([0.1, -0.25, 1.0]),
            Y_INC,
            (-1.0, 1.0),
        ),
    ],
)
def test_byte_and_ascii_records_and_their_rails(
    fmt: str,
    argument: bytes,
    preamble: bytes,
    data: bytes,
    volts: np.ndarray,
    lsb: float,
    rails: tuple[float, float],
) -> None:
    resource = ScriptedVisaResource(
        [
            IDN,
            (SET_UP.replace(b"FORM WORD", b"FORM " + argument), SETUP[1]),
            ACQUIRE,
            (PREAMBLE[0], b"+1;" + preamble + b"\n"),
            (b":WAV:DATA?\n", data + b"\n"),
        ]
    )
    device = ScpiScope(URL, 0.5, resource=resource, wave_format=fmt)
    record = device.acquire()
    resource.assert_done()
    np.testing.assert_allclose(record.samples, volts)
    assert record.dt_ns == pytest.approx(10.0) and record.clipped
    assert record.lsb == pytest.approx(lsb) and record.rails == pytest.approx(rails)


@pytest.mark.parametrize(
    "preamble, data, error, message",
    [
        (PREAMBLE_TEXT, b"#9000000006\x80\x00\x80\x10\x80\x00\n", ProtocolError, "preamble says 4"),
        (PREAMBLE_TEXT, b"#9000000008\x80\x00\x00\x00\x80\x10\x80\x00\n", DeviceError, "holes"),
        (PREAMBLE_TEXT.replace(b"+8,+5", b"+4,+5"), DATA[1], DeviceError, "asked for 8 averages"),
        (PREAMBLE_TEXT.replace(b"+1,+2", b"+0,+2"), None, ProtocolError, "format BYTE, asked"),
        (b"1,0,4", None, ProtocolError, "3 fields"),  # no data asked for
    ],
)
def test_a_record_that_does_not_add_up_is_refused(
    preamble: bytes, data: bytes | None, error: type[Exception], message: str
) -> None:
    dialogue = [CONFIGURE_8, ACQUIRE, (PREAMBLE[0], b"+1;" + preamble + b"\n")]
    if data is not None:
        dialogue.append((DATA[0], data))
    device, resource = scope(*dialogue)
    device.configure(5000.0, 400_000.0, 8)
    with pytest.raises(error, match=message):
        device.acquire()
    resource.assert_done()


def test_no_answer_is_a_timeout_naming_the_digitizer() -> None:
    device, resource = scope((b":WAV:DATA?\n", None))
    with pytest.raises(DeviceTimeout, match=r"digitizer at visa://TCPIP.*read waveform data"):
        device._block(":WAV:DATA?", "read waveform data", 0.05)
    resource.assert_done()
    assert resource.closed  # a late answer must not be read as the next one's


class TimedResource(ScriptedVisaResource):
    """The scripted resource, keeping the timeout (ms) of every read."""

    def __init__(self, dialogue: list[tuple[bytes, bytes | None]]):
        super().__init__(dialogue)
        self.read_timeouts_ms: list[float] = []

    def read_raw(self) -> bytes:
        self.read_timeouts_ms.append(self.timeout)
        return super().read_raw()

    def read_bytes(self, count: int, break_on_termchar: bool = False) -> bytes:
        self.read_timeouts_ms.append(self.timeout)
        return super().read_bytes(count, break_on_termchar)


def test_the_completion_may_take_the_acquisition_beyond_the_link_timeout() -> None:
    resource = TimedResource([IDN, SETUP, CONFIGURE_8, ACQUIRE, PREAMBLE, DATA])
    device = ScpiScope(URL, 0.5, resource=resource)
    device.configure(5000.0, 400_000.0, 8)
    record = device.acquire(timeout_s=0.25, acquisition_s=1.5)
    resource.assert_done()
    assert record.averages == 8
    # after identify, set up and configure (0.5 s each): *OPC? 1.5 s averaging + 0.25 s, then
    # the preamble and every read of the data block 0.25 s
    assert resource.read_timeouts_ms[:4] == [500.0, 500.0, 500.0, 1750.0]
    assert set(resource.read_timeouts_ms[4:]) == {250.0}


def test_a_scope_that_does_not_trigger_is_a_timeout_naming_the_trigger() -> None:
    device, resource = scope(CONFIGURE_8, (ACQUIRE[0], None))
    device.configure(5000.0, 400_000.0, 8)
    with pytest.raises(DeviceTimeout) as info:
        device.acquire(timeout_s=0.05, acquisition_s=0.016)
    resource.assert_done()
    assert info.value.device == "digitizer"
    assert str(info.value).endswith(
        "acquire: no record within 0.066 s (0.016 s of it for the acquisition of 8 averages, "
        "then timeout_s = 0.05 s for the link): no trigger on EXT rising through 1.4 V "
        "(sweep NORM)? Is the pulser's sync output wired there, and pulsing?"
    )
    assert resource.closed
    with pytest.raises(ValueError, match="acquisition_s"):
        device.acquire(timeout_s=0.05, acquisition_s=-1.0)
