"""A simulated pulser-receiver that serves a register map over Modbus TCP or RTU framing.

It serves whatever map it is given (``drivers.pulser.map_file``; ucal's own by default), so a
simulated cell can stand in for a device with another map.

The echo itself is injected: ``model(settings) -> (amplitude, tof_ns)`` gives the amplitude as a
fraction of full screen height and the round-trip time of flight in ns (NaN = no echo) at the
instant of the call, noise included. This module only plays the device: it applies the gate
and threshold, counts acquisitions, time-stamps them, and digitises an A-scan.

The A-scan's waveform may be injected too: ``ascan(request) -> samples`` (``AScanRequest``: the
record's start, interval and length, and the acquisition's echo and settings) gives the
receiver's output in fractions of full screen height, noise included; without one it is a
Gaussian-modulated cosine at the echo (``gaussian_pulse``). A gate longer than the A-scan's
memory (``ascan_samples``) at ``sample_rate_hz`` is sampled as fast as the memory allows, as a
scope does (with the injected waveform; the Gaussian keeps the first samples of the gate).
With ``bits`` the device's ADC
quantises it, its codes left-aligned in the int16 registers (full screen height is the top of
the register's range; a sample beyond the ADC's range sits on its rail); without, the samples are
rounded to the register. ``on_ascan_read(words)`` is told of every read of the A-scan, header
or samples (a simulated cell charges the transfer's time to its clock).

Acquisition policy (deterministic): every read of the measurement block — a read that holds
the map's ``measurement_trigger``, the reading's register the client reads first — is one new
acquisition: ``model`` is called once, the counter advances by one and the device clock is
sampled, and the read returns it. So ``read_gate(fresh=True)`` costs one round trip; the
time the acquisition takes (``averages`` pulses at ``prf_hz``) is the model's to let pass, as
the simulated cell's does (``ucal.sim.serve``, scaled by its time scale). The ``trigger``
command acquires too. Reading the A-scan header (its ``ascan_trigger``) freezes the
A-scan of the latest acquisition (acquiring first if there was none). A read or write of an
address the map does not declare is refused (illegal data address), a written value outside
the register's range or values too (illegal data value).

The server (pymodbus ``ModbusTcpServer``, framer ``SOCKET`` or ``RTU``) runs on 127.0.0.1 in a
background thread with its own asyncio loop. Faults for tests: :meth:`SimulatedPulser.set_silent`
(requests are received but never answered; the connection stays open) and
:meth:`SimulatedPulser.set_exception` (every request is answered with that exception code).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Self

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.framer import FramerType
from pymodbus.server import ModbusTcpServer

from drivers.loopback import ServedOnPort
from drivers.pulser import registers as reg
from drivers.pulser.base import PulserSettings
from drivers.pulser.map_file import register_map_of
from drivers.pulser.urls import format_rtu_url, format_tcp_url

log = logging.getLogger(__name__)

#: ``model(settings) -> (amplitude_fsh, tof_ns)``; NaN ``tof_ns`` means no echo.
PulserModel = Callable[[PulserSettings], tuple[float, float]]


@dataclass(frozen=True)
class AScanRequest:
    """What an A-scan holds: ``n`` samples from ``t0_ns`` every ``dt_ns``, of the acquisition
    whose echo is ``amplitude`` (fraction of full screen) at ``tof_ns`` (NaN: none), taken with
    ``settings``."""

    t0_ns: float
    dt_ns: float
    n: int
    amplitude: float
    tof_ns: float
    settings: PulserSettings


#: ``ascan(request) -> samples (n,)``: the receiver's output, fractions of full screen height.
AScanModel = Callable[[AScanRequest], np.ndarray]

#: −6 dB bandwidth of the simulated transducer, as a fraction of its centre frequency.
FRACTIONAL_BANDWIDTH = 0.6
#: What the simulated device reports in its device information block.
DEVICE_INFO = reg.DeviceInfo(model="ucal simulated", firmware=(2, 0), serial=1)
#: Longest wait for the server thread to start listening or to stop, s.
START_TIMEOUT_S = 5.0
STOP_TIMEOUT_S = 5.0

_FC_READ_HOLDING = int(reg.FunctionCode.READ_HOLDING_REGISTERS)
_FC_READ_INPUT = int(reg.FunctionCode.READ_INPUT_REGISTERS)
_FC_WRITE_SINGLE = int(reg.FunctionCode.WRITE_SINGLE_REGISTER)
#: The function code the datastore files each table under.
_FC_TABLE = {"holding": _FC_READ_HOLDING, "input": _FC_READ_INPUT}


def gaussian_pulse(
    time_ns: np.ndarray,
    tof_ns: float,
    amplitude: float,
    center_frequency_hz: float,
    fractional_bandwidth: float = FRACTIONAL_BANDWIDTH,
) -> np.ndarray:
    """Return a Gaussian-modulated cosine echo peaking at ``tof_ns`` (ns), height ``amplitude``.

    The envelope ``exp(-t²/2σ²)`` has a spectrum whose −6 dB full width is
    ``fractional_bandwidth · center_frequency_hz``: σ = √(2 ln 2) / (π · bw · f_c).
    """
    t_s = (np.asarray(time_ns, float) - tof_ns) * 1e-9
    sigma_s = math.sqrt(2.0 * math.log(2.0)) / (
        math.pi * fractional_bandwidth * center_frequency_hz
    )
    envelope = np.exp(-0.5 * (t_s / sigma_s) ** 2)
    return amplitude * envelope * np.cos(2.0 * math.pi * center_frequency_hz * t_s)


class _PulserContext(ModbusDeviceContext):
    """pymodbus device context whose reads and writes go through the simulated device.

    The register image lives in two ``ModbusSequentialDataBlock`` created at block address
    ``DATASTORE_OFFSET`` (= 1), because ``ModbusDeviceContext.getValues``/``setValues`` add 1
    to the protocol address: protocol address N is ``values[N]`` of each block.
    """

    def __init__(self, device: SimulatedPulser):
        spans = {t: max(device.register_map.span(t), 1) for t in ("holding", "input")}
        super().__init__(
            hr=ModbusSequentialDataBlock(reg.DATASTORE_OFFSET, [0] * spans["holding"]),
            ir=ModbusSequentialDataBlock(reg.DATASTORE_OFFSET, [0] * spans["input"]),
        )
        self._device = device

    async def async_getValues(
        self, func_code: int, address: int, count: int = 1
    ) -> list[int] | list[bool] | ExcCodes:
        return self._device._get(func_code, address, count)

    async def async_setValues(
        self, func_code: int, address: int, values: list[int] | list[bool]
    ) -> ExcCodes | None:
        return self._device._set(func_code, address, values)


class SimulatedPulser(ServedOnPort):
    """A pulser-receiver on 127.0.0.1 whose echo comes from ``model``. Use as a context manager.

    ``framing`` is ``"tcp"`` (Modbus TCP) or ``"rtu"`` (Modbus RTU frames over a TCP stream,
    reached through pyserial's ``socket://``). ``port`` 0 picks a free port; :attr:`url` tells
    it after :meth:`start`. ``center_frequency_hz`` and ``sample_rate_hz`` shape the A-scan.
    ``register_map`` is the map served (a ``RegisterMap`` or a map file; None: ucal's own); the
    device reports the highest version it lists. Nothing is opened before :meth:`start`.
    """

    what = "simulated pulser"

    def __init__(
        self,
        model: PulserModel,
        framing: str = "tcp",
        host: str = "127.0.0.1",
        port: int = 0,
        unit: int = 1,
        center_frequency_hz: float = 25e6,
        sample_rate_hz: float = 100e6,
        register_map: reg.RegisterMap | str | Path | None = None,
        *,
        bits: int | None = None,
        ascan: AScanModel | None = None,
        on_ascan_read: Callable[[int], None] | None = None,
    ):
        if bits is not None and not 4 <= int(bits) <= 16:
            raise ValueError(f"bits must be 4 … 16, got {bits!r}")
        register_map = self.register_map = register_map_of(register_map)
        self._version = max(register_map.versions) if register_map.versions else None
        if not callable(model):
            raise TypeError("model must be callable: model(settings) -> (amplitude, tof_ns)")
        if framing not in ("tcp", "rtu"):
            raise ValueError(f"framing must be 'tcp' or 'rtu', got {framing!r}")
        if not _is_loopback(host):
            raise ValueError(f"the simulated pulser serves on loopback only, got host {host!r}")
        if not 0 <= int(port) <= 65535:
            raise ValueError(f"port must be 0 … 65535, got {port!r}")
        if not 1 <= int(unit) <= 247:
            raise ValueError(f"unit must be 1 … 247, got {unit!r}")
        for name, value in (
            ("center_frequency_hz", center_frequency_hz),
            ("sample_rate_hz", sample_rate_hz),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive frequency in Hz, got {value!r}")
        self.model = model
        self.framing = framing
        self.host = host
        self.unit = int(unit)
        self.center_frequency_hz = float(center_frequency_hz)
        self.sample_rate_hz = float(sample_rate_hz)
        self.bits = None if bits is None else int(bits)
        self.ascan = ascan
        self.on_ascan_read = on_ascan_read
        self._requested_port = int(port)
        self._port: int | None = None
        self._lock = threading.RLock()
        self._silent = False
        self._exception: ExcCodes | None = None
        self._context = _PulserContext(self)
        self._counter = 0
        self._acquisitions = 0
        self._echo: tuple[float, float] = (0.0, float("nan"))  # latest raw (amp, tof_ns)
        self._fc6_echo: list[int] = []
        # the settings and gate threshold the holding registers hold, decoded on the first
        # acquisition after a write (every acquisition reads them, only a write changes them)
        self._decoded: tuple[PulserSettings, float] | None = None
        self._t0 = time.monotonic()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._reset_registers()

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> Self:
        """Start serving (idempotent); return self. Raises ``RuntimeError`` if it cannot."""
        if self._thread is not None:
            return self
        self._ready.clear()
        self._error = None
        self._stopping = asyncio.Event()
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="simulated-pulser", daemon=True)
        self._thread.start()
        if not self._ready.wait(START_TIMEOUT_S):
            self.stop()
            raise RuntimeError(f"simulated pulser did not start within {START_TIMEOUT_S:g} s")
        if self._error is not None:
            error = self._error
            self.stop()
            raise RuntimeError(
                f"simulated pulser could not listen on {self.host}:{self._requested_port}: {error}"
            ) from error
        log.info("simulated pulser serving %s", self.url)
        return self

    def stop(self) -> None:
        """Stop serving and close every connection. Idempotent; returns within ~5 s at most."""
        thread, loop, stopping = self._thread, self._loop, self._stopping
        if thread is None:
            return
        if loop is not None and stopping is not None:
            with contextlib.suppress(RuntimeError):  # loop closed: the thread is ending
                loop.call_soon_threadsafe(stopping.set)
        thread.join(STOP_TIMEOUT_S)
        if thread.is_alive():
            log.warning("simulated pulser thread did not stop within %g s", STOP_TIMEOUT_S)
        self._thread = None
        self._loop = None
        self._port = None

    @property
    def url(self) -> str:
        """``modbus-tcp://127.0.0.1:PORT?unit=1`` or ``modbus-rtu://socket://127.0.0.1:PORT?unit=1``."""
        if self.framing == "tcp":
            return format_tcp_url(self.host, self.port, self.unit)
        return format_rtu_url(f"socket://{self.host}:{self.port}", self.unit)

    # --- fault hooks and state for tests ----------------------------------------------------
    def set_exception(self, code: int | None) -> None:
        """Answer every following request with Modbus exception ``code``; None to stop.

        ``code`` is a standard exception code (1 … 8, 10, 11), e.g. 2 = illegal data address.
        """
        with self._lock:
            if code is None:
                self._exception = None
                return
            try:
                self._exception = ExcCodes(int(code))
            except ValueError:
                raise ValueError(f"not a Modbus exception code: {code!r}") from None

    @property
    def counter(self) -> int:
        """The reading counter (number of acquisitions since the last clear, mod 2**32)."""
        with self._lock:
            return self._counter

    @property
    def acquisitions(self) -> int:
        """How many times ``model`` was called."""
        with self._lock:
            return self._acquisitions

    @property
    def settings(self) -> PulserSettings:
        """The settings currently in the holding registers."""
        with self._lock:
            return self._held()[0]

    @property
    def gate_threshold(self) -> float:
        """The gate threshold, fraction of full screen height."""
        with self._lock:
            return self._held()[1]

    # --- the device -------------------------------------------------------------------------
    def _holding(self) -> list[int]:
        values = self._context.getValues(_FC_READ_HOLDING, 0, self.register_map.span("holding"))
        assert isinstance(values, list)  # the whole holding block: never an exception code
        return list(values)

    def _settings(self, holding: Sequence[int]) -> PulserSettings:
        present = self.register_map.present(reg.SETTINGS + reg.FRONT_END, self._version)
        return self.register_map.decode_settings(
            {r.name: holding[r.address : r.end] for r in present}
        )

    def _threshold(self, holding: Sequence[int]) -> float:
        r = self.register_map.get("threshold")
        return reg.DEFAULT_THRESHOLD if r is None else r.decode_value(holding[r.address : r.end])

    def _held(self) -> tuple[PulserSettings, float]:
        """The settings and the gate threshold in the holding registers (decoded once a write)."""
        if self._decoded is None:
            holding = self._holding()
            self._decoded = (self._settings(holding), self._threshold(holding))
        return self._decoded

    def _put(self, entries: list[tuple[reg.Register, list[int]]]) -> None:
        """Store registers' words in their tables, each run of neighbours in one store."""
        runs: list[tuple[str, int, list[int]]] = []
        for r, words in sorted(entries, key=lambda e: (e[0].table, e[0].address)):
            if r.table == "holding":
                self._decoded = None
            if runs and runs[-1][0] == r.table and runs[-1][1] + len(runs[-1][2]) == r.address:
                runs[-1][2].extend(words)
            else:
                runs.append((r.table, r.address, list(words)))
        for table, address, values in runs:
            self._context.setValues(_FC_TABLE[table], address, values)

    def _reset_registers(self) -> None:
        """Power-on state: default settings and threshold, zeroed measurement, identity."""
        m = self.register_map
        self._put(m.power_on())
        magic, version, model = m.get("magic"), m.get("map_version"), m.get("model")
        if magic is not None and magic.values:
            self._put([(magic, magic.encode(int(magic.values[0])))])
        if version is not None:
            self._put([(version, version.encode(self._version or 0))])
        name = DEVICE_INFO.model or ""
        info = DEVICE_INFO if model is None else replace(DEVICE_INFO, model=name[: 2 * model.words])
        self._put(m.encode_device_info(info))
        self._store_measurement(reg.Measurement(0, 0, reg.Status(0), 0.0, float("nan")))

    def _store_measurement(self, m: reg.Measurement) -> None:
        self._put(self.register_map.encode_measurement(m))

    def _get(self, func_code: int, address: int, count: int) -> list[int] | list[bool] | ExcCodes:
        """Serve a read (protocol address, server thread)."""
        with self._lock:
            if self._exception is not None:
                return self._exception
            if func_code == _FC_WRITE_SINGLE:  # pymodbus reads back the register to echo it
                return list(self._fc6_echo)
            table = {"h": "holding", "i": "input"}.get(self._context.decode(func_code))
            if table is None:
                return ExcCodes.ILLEGAL_FUNCTION
            m = self.register_map
            if address < 0 or not m.declared(table, address, count):
                return ExcCodes.ILLEGAL_ADDRESS

            def holds(r: reg.Register | None) -> bool:
                return r is not None and r.table == table and address <= r.address < address + count

            if holds(m.measurement_trigger) and not self._acquire():
                return ExcCodes.DEVICE_FAILURE
            if holds(m.ascan_trigger) and not self._freeze_ascan():
                return ExcCodes.DEVICE_FAILURE
            samples = m.get("ascan_samples")
            if self.on_ascan_read is not None and (
                holds(m.ascan_trigger)
                or (
                    samples is not None
                    and samples.table == table
                    and address < samples.end
                    and samples.address < address + count
                )
            ):
                self.on_ascan_read(count)
            return self._context.getValues(func_code, address, count)

    def _set(self, func_code: int, address: int, values: list[int] | list[bool]) -> ExcCodes | None:
        """Serve a write (protocol address, server thread): validate, store, run commands."""
        with self._lock:
            if self._exception is not None:
                return self._exception
            if self._context.decode(func_code) != "h":
                return ExcCodes.ILLEGAL_FUNCTION
            m = self.register_map
            if address < 0 or not m.declared("holding", address, len(values)):
                return ExcCodes.ILLEGAL_ADDRESS
            image = self._holding()
            image[address : address + len(values)] = [int(v) for v in values]
            for r in m.registers.values():
                if r.table != "holding" or r.end <= address or r.address >= address + len(values):
                    continue  # not written
                if not r.writable:
                    return ExcCodes.ILLEGAL_ADDRESS
                raw = r.decode(image[r.address : r.end])
                if not r.raw_ok(raw):
                    log.debug("simulated pulser: rejected %s raw %r", r.name, raw)
                    return ExcCodes.ILLEGAL_VALUE
            try:
                self._settings(image)
            except ValueError as exc:  # each register in range, together meaningless
                log.debug("simulated pulser: rejected settings: %s", exc)
                return ExcCodes.ILLEGAL_VALUE
            command = "none"
            command_register = m.get("command")
            if command_register is not None:
                c = command_register
                raw = c.decode(image[c.address : c.end])
                command = next(name for name, v in c.names.items() if v == raw)
                image[c.address : c.end] = c.encode(c.names["none"])  # write-only: reads none
            self._context.setValues(_FC_READ_HOLDING, 0, image)
            self._decoded = None
            if func_code == _FC_WRITE_SINGLE:
                self._fc6_echo = [int(v) for v in values]
            if command == "trigger" and not self._acquire():
                return ExcCodes.DEVICE_FAILURE
            if command == "clear_counter":
                self._counter = 0
                self._store_measurement(reg.Measurement(0, 0, reg.Status(0), 0.0, float("nan")))
            return None

    def _acquire(self) -> bool:
        """One acquisition: call the model once, gate it, store the measurement block."""
        settings, threshold = self._held()
        try:
            reg.check_gate(settings)
        except ValueError:
            amp, tof, status = 0.0, float("nan"), reg.Status.GATE_ERROR
            self._echo = (0.0, float("nan"))
        else:
            try:
                raw_amp, raw_tof = self.model(settings)
                raw_amp, raw_tof = float(raw_amp), float(raw_tof)
            except Exception:  # a failing model is a device failure, not a server crash
                log.exception("simulated pulser: the echo model failed")
                return False
            self._acquisitions += 1
            if not math.isfinite(raw_amp) or raw_amp < 0.0:
                raw_amp = 0.0
            self._echo = (raw_amp, raw_tof)
            amp, tof, status = self._gate(settings, threshold, raw_amp, raw_tof)
        self._counter = (self._counter + 1) & 0xFFFF_FFFF
        time_ms = int((time.monotonic() - self._t0) * 1000.0) & 0xFFFF_FFFF
        self._store_measurement(reg.Measurement(self._counter, time_ms, status, amp, tof))
        return True

    @staticmethod
    def _gate(
        settings: PulserSettings, threshold: float, amp: float, tof_ns: float
    ) -> tuple[float, float, reg.Status]:
        """Apply the gate and threshold to the raw echo: (amplitude, tof_ns, status)."""
        start_ns, end_ns = settings.gate_ns
        if math.isfinite(tof_ns) and not start_ns <= tof_ns <= end_ns:
            return 0.0, float("nan"), reg.Status(0)  # the echo is outside the gate
        status = reg.Status(0)
        if amp >= 1.0:
            amp, status = 1.0, reg.Status.SATURATED
        if math.isfinite(tof_ns) and amp >= threshold:
            return amp, tof_ns, status | reg.Status.ECHO
        return amp, float("nan"), status

    def _freeze_ascan(self) -> bool:
        """Synthesise the A-scan of the latest acquisition over the gate; store header+samples."""
        if self._counter == 0 and not self._acquire():
            return False
        settings = self._held()[0]
        start_ns = round(settings.gate_start_us * 1e3)
        samples = self.register_map["ascan_samples"]
        rate_hz = self.sample_rate_hz
        try:
            reg.check_gate(settings)
            n = round(settings.gate_width_us * 1e-6 * rate_hz) + 1
            if n > samples.words and self.ascan is not None:
                # a gate longer than the memory: sampled as fast as the memory allows (as a
                # scope does), at a rate the header's float32 carries exactly
                rate_hz = float(np.float32((samples.words - 1) / (settings.gate_width_us * 1e-6)))
                n = round(settings.gate_width_us * 1e-6 * rate_hz) + 1
            n = min(n, samples.words)
        except ValueError:
            n = 0
        dt_ns = 1e9 / rate_hz
        amp, tof_ns = self._echo
        if self.ascan is not None and n:
            try:
                wave = np.asarray(
                    self.ascan(AScanRequest(float(start_ns), dt_ns, n, amp, tof_ns, settings)),
                    float,
                )
            except Exception:  # a failing model is a device failure, not a server crash
                log.exception("simulated pulser: the A-scan model failed")
                return False
        elif math.isfinite(tof_ns) and amp > 0.0:
            wave = gaussian_pulse(
                start_ns + np.arange(n) * dt_ns, tof_ns, amp, self.center_frequency_hz
            )
        else:
            wave = np.zeros(n)
        header = reg.AScanHeader(self._counter, n, rate_hz, start_ns)
        self._put(self.register_map.encode_ascan_header(header))
        if n:
            self._put([(samples, self._digitise(wave, samples.full_scale))])
        return True

    def _digitise(self, wave: np.ndarray, full_scale: int) -> list[int]:
        """The A-scan's registers: the ADC's codes left-aligned in int16 (module docstring)."""
        if self.bits is None:
            return reg.encode_samples(wave, full_scale)
        shift = 2 ** (16 - self.bits)
        top = 2 ** (self.bits - 1)
        codes = np.clip(np.rint(wave * full_scale / shift), -top, top - 1) * shift
        words: list[int] = (codes.astype(np.int16).view(np.uint16)).astype(int).tolist()
        return words

    # --- server thread ----------------------------------------------------------------------
    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """Log frames; drop answers while silent (pymodbus ``trace_packet`` hook)."""
        if not sending:
            log.debug("simulated pulser READ: %s", data.hex(" "))
            return data
        with self._lock:
            silent = self._silent
        if silent:
            log.debug("simulated pulser (silent) drops: %s", data.hex(" "))
            return b""
        log.debug("simulated pulser WRITE: %s", data.hex(" "))
        return data

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:
            self._error = exc
        finally:
            self._ready.set()
            pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
            for task in pending:
                task.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    async def _serve(self) -> None:
        assert self._stopping is not None
        context = ModbusServerContext(devices={self.unit: self._context}, single=False)
        server = ModbusTcpServer(
            context,
            framer=FramerType.RTU if self.framing == "rtu" else FramerType.SOCKET,
            address=(self.host, self._requested_port),
            # a serial device with another address stays silent; a TCP gateway answers 0x0B
            ignore_missing_devices=self.framing == "rtu",
            trace_packet=self._trace_packet,
        )
        await server.serve_forever(background=True)
        try:
            listener: Any = server.transport
            self._port = int(listener.sockets[0].getsockname()[1])
            self._ready.set()
            await self._stopping.wait()
        finally:
            await server.shutdown()


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
