"""What each register name of a pulser's register map means to ucal: its name and unit for
the value (``QUANTITIES``), the units a map may state it in (``UNITS``), the groups of
registers requests carry (``SETTINGS``, ``MEASUREMENT`` …), and the codes a reading's status
and the command register hold. ``drivers.pulser.map_file`` checks a map file against them.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

#: Longest A-scan a map may declare, samples (327.68 µs at 100 MS/s).
ASCAN_MAX_SAMPLES = 32768
#: Registers of the measurement block of ucal's own map (counter … TOF): what one reading
#: costs on the wire (``ucal.timing``).
MEASUREMENT_COUNT = 10
#: Gate threshold of a freshly powered device, fraction of full screen height.
DEFAULT_THRESHOLD = 0.02


class Status(enum.IntFlag):
    """What a reading's status says (the map's ``status`` register places each on a bit)."""

    ECHO = 0x0001  #: an echo inside the gate crossed the threshold; TOF is valid
    SATURATED = 0x0002  #: the gated peak reached full screen (amplitude clipped at 1.0)
    GATE_ERROR = 0x0004  #: the gate ends after the pulse repetition period; no measurement


#: Names of the status bits in a map file (``bits``), and the flag each one sets.
STATUS_BITS: dict[str, Status] = {
    "echo": Status.ECHO,
    "saturated": Status.SATURATED,
    "gate_error": Status.GATE_ERROR,
}
#: Names of the command register's values in a map file (``values``); ``none`` is what it
#: reads after a command ran.
COMMANDS = ("none", "trigger", "clear_counter")


@dataclass(frozen=True)
class Quantity:
    """What a register name of a map file means: ucal's name and unit for it, its dimension
    (which units a map may state it in), and the group of requests it travels in."""

    ucal_name: str  #: ucal's name (a ``PulserSettings`` field, or the reading's), in messages
    dimension: str  #: a key of :data:`UNITS`, or "count", "code", "text", "samples"
    unit: str  #: ucal's unit
    group: str  #: settings, front_end, threshold, command, identity, info, measurement, ascan
    required: bool = False


#: Every register name a map may hold, with its meaning and whether every map must have it.
QUANTITIES: dict[str, Quantity] = {
    # holding registers the client writes
    "gain": Quantity("gain_db", "gain", "dB", "settings", required=True),
    "prf": Quantity("prf_hz", "frequency", "Hz", "settings", required=True),
    "gate_start": Quantity("gate_start_us", "time", "µs", "settings", required=True),
    "gate_width": Quantity("gate_width_us", "time", "µs", "settings", required=True),
    "averages": Quantity("averages", "count", "", "settings", required=False),
    "pulse_voltage": Quantity("pulse_voltage_v", "voltage", "V", "front_end", required=False),
    "damping": Quantity("damping_ohm", "resistance", "Ω", "front_end", required=False),
    "high_pass": Quantity("high_pass_mhz", "frequency", "MHz", "front_end", required=False),
    "low_pass": Quantity("low_pass_mhz", "frequency", "MHz", "front_end", required=False),
    "threshold": Quantity("gate_threshold", "fraction", "FSH", "threshold", required=False),
    "command": Quantity("command", "code", "", "command", required=False),
    # what the client reads
    "magic": Quantity("magic", "code", "", "identity", required=False),
    "map_version": Quantity("register_map_version", "code", "", "identity", required=False),
    "model": Quantity("model", "text", "", "info", required=False),
    "firmware_major": Quantity("firmware_major", "code", "", "info", required=False),
    "firmware_minor": Quantity("firmware_minor", "code", "", "info", required=False),
    "serial": Quantity("serial", "code", "", "info", required=False),
    "counter": Quantity("counter", "count", "", "measurement", required=False),
    "device_time": Quantity("device_time_ms", "time", "ms", "measurement", required=False),
    "status": Quantity("status", "code", "", "measurement", required=False),
    "amplitude": Quantity("amplitude", "fraction", "FSH", "measurement", required=True),
    "tof": Quantity("tof_ns", "time", "ns", "measurement", required=True),
    "ascan_counter": Quantity("ascan_counter", "count", "", "ascan", required=False),
    "ascan_length": Quantity("ascan_length", "count", "", "ascan", required=False),
    "ascan_rate": Quantity("sample_rate_hz", "frequency", "Hz", "ascan", required=False),
    "ascan_start": Quantity("ascan_start_ns", "time", "ns", "ascan", required=False),
    "ascan_samples": Quantity("samples", "samples", "FSH", "ascan", required=False),
}

#: Units a map may state each dimension in: unit → its size in the dimension's base unit.
UNITS: dict[str, dict[str, int | float]] = {
    "gain": {"dB": 1},
    "frequency": {"Hz": 1, "kHz": 1_000, "MHz": 1_000_000},
    "time": {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "µs": 1_000, "ns": 1, "ps": 1e-3},
    "voltage": {"V": 1, "kV": 1_000},
    "resistance": {"ohm": 1, "Ω": 1},
    "fraction": {"FSH": 1, "%": 1e-2},
}

#: The ``PulserSettings`` fields of the first configure request, and of the front end, by
#: register name (register order of ucal's map).
SETTINGS = ("gain", "prf", "gate_start", "gate_width", "averages")
FRONT_END = ("pulse_voltage", "damping", "high_pass", "low_pass")
#: The reading, the device information and the A-scan header, by register name.
MEASUREMENT = ("counter", "device_time", "status", "amplitude", "tof")
DEVICE_INFO = ("model", "firmware_major", "firmware_minor", "serial")
ASCAN_HEADER = ("ascan_counter", "ascan_length", "ascan_rate", "ascan_start")
