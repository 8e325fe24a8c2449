"""The simulated scope of each family through PyVISA (pyvisa-py, a raw TCPIP SOCKET on
127.0.0.1), as a user's script meets it: every IEEE 488.2 mandatory common command answered
with the status model's meaning, the commands a script sends taken (and those of the other
family refused, −113 in the error queue), and the driver against it: the trigger set and read
back, a record of the echo, an untriggered record refused, no trigger a timeout naming it."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers.digitizer.scpi_simulator import AcquisitionRequest, SimulatedScope
from drivers.digitizer.visa import ScpiScope
from drivers.errors import DeviceError, DeviceTimeout

pytestmark = pytest.mark.system

FAMILIES = ["keysight", "rigol"]
#: ``*IDN?``'s manufacturer and the family's "no error" entry.
MAKERS = {"keysight": "KEYSIGHT TECHNOLOGIES", "rigol": "RIGOL TECHNOLOGIES"}
NO_ERROR = {"keysight": '+0,"No error"', "rigol": '0,"No error"'}


def echo(request: AcquisitionRequest) -> np.ndarray:
    """A 0.5 V tone burst 40 µs after the pulse."""
    t = request.t_ns - 40_000.0
    return 0.5 * np.exp(-((t / 40.0) ** 2)) * np.cos(2 * np.pi * 0.025 * t)


@pytest.fixture(params=FAMILIES)
def family(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def sim(family: str) -> Iterator[SimulatedScope]:
    with SimulatedScope(echo, family=family) as scope:
        yield scope


@pytest.fixture
def session(sim: SimulatedScope) -> Iterator:  # type: ignore[type-arg]
    import pyvisa

    manager = pyvisa.ResourceManager("@py")
    resource = manager.open_resource(
        sim.resource, read_termination="\n", write_termination="\n", timeout=2000
    )
    yield resource
    resource.close()
    manager.close()


def number(answer: str) -> int:
    return int(answer.strip())


# --- IEEE 488.2 -----------------------------------------------------------------------------


def test_every_mandatory_common_command_is_answered_as_ieee_488_2_says(
    session, family: str
) -> None:  # type: ignore[no-untyped-def]
    q = session.query
    # *IDN?: four fields; *ESR?: power on (bit 7) at first, cleared by reading it
    manufacturer, model, serial, firmware = q("*IDN?").split(",")
    assert manufacturer == MAKERS[family] and serial == "UCAL-SIM" and model and firmware
    assert number(q("*ESR?")) == 128
    assert number(q("*ESR?")) == 0
    # *ESE / *ESE?, *SRE / *SRE? (bit 6 of the service request enable is not one)
    session.write("*ESE 36")
    assert number(q("*ESE?")) == 36
    session.write("*SRE 255")
    assert number(q("*SRE?")) == 191
    session.write("*SRE 32")
    assert number(q("*SRE?")) == 32
    # a command error sets ESR bit 5, summarised in the status byte's ESB (enabled by *ESE)
    # and MSS (ESB enabled by *SRE); the error is in the queue
    session.write(":NO:SUCH:COMMand 1")
    assert number(q("*STB?")) == 32 + 64
    assert number(q("*ESR?")) == 32
    assert number(q("*STB?")) == 0
    assert q(":SYST:ERR?") == '-113,"Undefined header"'
    assert q(":SYST:ERR?") == NO_ERROR[family]
    # an execution error (a value the setting does not take) is ESR bit 4
    session.write(":TRIG:SWE SIDEWAYS")
    assert number(q("*ESR?")) == 16
    assert q(":SYST:ERR?") == '-224,"Illegal parameter value"'
    # *CLS clears the event register and the error queue
    session.write(":NO:SUCH:COMMand")
    session.write("*CLS")
    assert number(q("*ESR?")) == 0 and q(":SYST:ERR?") == NO_ERROR[family]
    # *OPC sets ESR bit 0 once every operation is complete; *OPC? answers 1; *WAI waits
    session.write("*OPC")
    assert number(q("*ESR?")) == 1
    assert q("*OPC?") == "1"
    session.write("*WAI")
    # *TST?: 0, the self-test passed
    assert number(q("*TST?")) == 0
    # MAV: a message waits in the output queue while the status byte is read
    first, stb = q("*IDN?;*STB?").rsplit(";", 1)
    assert first.startswith(MAKERS[family]) and number(stb) & 16
    # *RST: every setting back at its power-on value (the sweep AUTO)
    session.write(":TRIG:SWE NORM")
    assert q(":TRIG:SWE?") == "NORM"
    session.write("*RST")
    assert q(":TRIG:SWE?") == "AUTO"
    assert number(q("*ESR?")) == 0 and q(":SYST:ERR?") == NO_ERROR[family]


@pytest.mark.parametrize("value", ["", "256", "-1", "many"])
def test_a_status_register_value_out_of_its_byte_is_an_error(session, value: str) -> None:  # type: ignore[no-untyped-def]
    session.write("*CLS")
    session.write(f"*ESE {value}".strip())
    assert number(session.query("*ESE?")) == 0
    assert session.query(":SYST:ERR?").split(",")[0] in ("-109", "-222", "-104", "+0")


# --- what a script sends --------------------------------------------------------------------

SCRIPTS = {
    "keysight": [
        (":RUN", None),
        (":STOP", None),
        (":TIMebase:SCALe 1E-5", ("TIM:RANG?", 1e-4)),  # 10 divisions
        (":TIMebase:POSition 2E-5", ("TIM:POS?", 2e-5)),
        (":TRIGger:SWEep NORMal", ("TRIG:SWE?", "NORM")),
        (":TRIGger:SOURce EXTernal", ("TRIG:EDGE:SOUR?", "EXT")),  # [:EDGE] left out
        (":TRIGger:EDGE:LEVel 0.5", ("TRIG:LEV?", 0.5)),
        (":ACQuire:TYPE AVERage;COUNt 16", ("ACQ:COUN?", "16")),
        (":WAVeform:FORMat ASCii", ("WAV:FORM?", "ASC")),
        (":CHANnel1:SCALe 0.1", ("CHAN1:RANG?", 0.8)),  # 8 divisions
        (":SINGle", None),
    ],
    "rigol": [
        (":RUN", None),
        (":STOP", None),
        (":TIMebase:MAIN:SCALe 2E-6", ("TIM:SCAL?", 2e-6)),  # [:MAIN] left out
        (":TIMebase:SCALe 3E-6", ("TIM:MAIN:SCAL?", 2e-6)),  # the nearest 1-2-5 step
        (":TIMebase:MAIN:OFFSet 1E-5", ("TIM:MAIN:OFFS?", 1e-5)),
        (":TRIGger:SWEep NORMal", ("TRIG:SWE?", "NORM")),
        (":TRIGger:EDGe:SOURce CHANnel2", ("TRIG:EDG:SOUR?", "CHAN2")),
        (":TRIGger:EDGe:LEVel 1.0", ("TRIG:EDG:LEV?", 1.0)),
        (":ACQuire:TYPE AVERages", ("ACQ:TYPE?", "AVER")),
        (":ACQuire:AVERages 64", ("ACQ:AVER?", "64")),
        (":WAVeform:MODE RAW", ("WAV:MODE?", "RAW")),
        (":SINGle", ("TRIG:STAT?", "TD")),
        (":TFORce", ("TRIG:STAT?", "STOP")),
    ],
}


def test_the_commands_a_script_sends_are_taken(session, family: str) -> None:  # type: ignore[no-untyped-def]
    session.write("*CLS")
    for command, check in SCRIPTS[family]:
        session.write(command)
        assert session.query(":SYST:ERR?") == NO_ERROR[family], command
        if check is not None:
            query, expected = check
            answer = session.query(":" + query)
            if isinstance(expected, float):
                assert float(answer) == pytest.approx(expected), command
            else:
                assert answer == expected, command


@pytest.mark.parametrize(
    "family, header",
    [
        # what a Rigol DS1000Z has none of (the Keysight's commands)
        ("rigol", ":DIG"),
        ("rigol", ":WAV:POIN:MODE RAW"),
        ("rigol", ":WAV:UNS 1"),
        ("rigol", ":WAV:BYT MSBF"),
        ("rigol", ":ACQ:COUN 8"),
        ("rigol", ":TIM:RANG 1E-4"),
        ("rigol", ":TIM:POS 0"),
        ("rigol", ":TIM:REF LEFT"),
        ("rigol", ":TER?"),
        # and what an InfiniiVision has none of (the Rigol's)
        ("keysight", ":TRIG:STAT?"),
        ("keysight", ":ACQ:AVER 8"),
        ("keysight", ":WAV:MODE RAW"),
        ("keysight", ":TFOR"),
    ],
)
def test_the_other_familys_commands_are_undefined_headers(session, header: str) -> None:  # type: ignore[no-untyped-def]
    session.write("*CLS")
    session.write(header)
    assert session.query(":SYST:ERR?").startswith('-113,"Undefined header"')


# --- the driver against it ------------------------------------------------------------------


def test_the_driver_sets_the_trigger_and_records_the_echo(sim: SimulatedScope, family: str) -> None:
    with ScpiScope(sim.url, 1.0) as device:
        assert device.identity()["family"] == family
        source, level, sweep = (
            sim.state[sim.family.roles[r]] for r in ("source", "level", "sweep")
        )
        assert (source, float(level), sweep) == (sim.sync_input, 1.4, "NORM")
        device.configure(20_000.0, 50_000.0, 16)
        record = device.acquire()
    assert record.t0_ns == pytest.approx(20_000.0) and record.dt_ns == pytest.approx(5.0)
    assert record.n == 10_001 and record.averages == 16
    peak = int(np.argmax(np.abs(record.samples)))
    assert record.t0_ns + peak * record.dt_ns == pytest.approx(40_000.0, abs=2.5)
    assert np.max(record.samples) == pytest.approx(0.5, abs=0.02)


def test_a_keysight_left_in_auto_hands_over_an_untriggered_record_which_is_refused() -> None:
    # the sync output is not on EXT; someone set the sweep to AUTO behind ucal's back
    with (
        SimulatedScope(echo, family="keysight", sync_input="CHAN3") as sim,
        ScpiScope(sim.url, 1.0) as device,
    ):
        device.configure(20_000.0, 50_000.0, 1)
        sim.execute(":TRIG:SWE AUTO")
        with pytest.raises(DeviceError, match="arrived untriggered"):
            device.acquire()
        assert sim.acquisitions == 1  # it did acquire, untriggered


@pytest.mark.parametrize("family", FAMILIES)
def test_a_scope_the_sync_output_does_not_reach_is_a_timeout_naming_the_trigger(
    family: str,
) -> None:
    with SimulatedScope(echo, family=family, sync_input="CHAN4") as sim:
        device = ScpiScope(sim.url, 1.0)
        device.connect()
        device.configure(20_000.0, 50_000.0, 1)
        with pytest.raises(DeviceTimeout, match=r"no trigger on \w+ rising through 1.4 V"):
            device.acquire(timeout_s=0.2)
        assert sim.acquisitions == 0
        device.close()


def test_the_error_queue_holds_30_and_says_it_overflowed(session, family: str) -> None:  # type: ignore[no-untyped-def]
    session.write("*CLS")
    for _ in range(31):
        session.write(":NO:SUCH")
    errors = [session.query(":SYST:ERR?") for _ in range(31)]
    assert errors[:29] == ['-113,"Undefined header"'] * 29
    assert errors[29:] == ['-350,"Queue overflow"', NO_ERROR[family]]


def test_data_before_any_acquisition_is_stale(session) -> None:  # type: ignore[no-untyped-def]
    session.write("*CLS")
    session.write(":WAV:PRE?")  # nothing acquired yet: no answer, an error
    assert session.query(":SYST:ERR?").startswith('-230,"Data corrupt or stale"')


def test_a_rigol_reads_its_screen_or_its_memory() -> None:
    with SimulatedScope(echo, family="rigol") as sim:
        sim.execute(":TRIG:EDG:SOUR CHAN2;:TRIG:EDG:LEV 1;:TIM:MAIN:SCAL 5E-6;:SING")
        assert sim.execute(":WAV:MODE NORM;:WAV:PRE?") == (
            b"0,0,1200,1,5.000000e-08,-3.000000e-05,0,4.000000e-02,0,127\n"  # 5 µs/100
        )
        raw = sim.execute(":WAV:MODE RAW;:WAV:PRE?")
        assert raw is not None and raw.startswith(b"0,2,12001,1,5.000000e-09,-3.000000e-05,")
