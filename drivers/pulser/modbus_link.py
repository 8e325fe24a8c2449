"""The Modbus link to the pulser-receiver: the pymodbus synchronous client (RTU over a serial
line or pyserial URL, or TCP), one request at a time within its timeout, every pymodbus and
pyserial fault mapped to ``drivers.errors`` (``drivers.pulser.modbus`` lists the mapping), the
DEBUG log of every frame (``WRITE:``/``READ:`` in hex), and the registers of the map read and
written by name. ``drivers.pulser.modbus.ModbusPulser`` derives from :class:`ModbusLink` and
gives the registers their meaning.

A read's timeout is the link's ``timeout_s`` plus what the read itself takes: over RTU the
time its frames take on the line at the URL's baud (``rtu_read_line_s``; over TCP none), and
for a read that makes the device acquire, the acquisition (``busy_s``); a deadline of the
whole operation shortens it. A write waits ``timeout_s``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.client.base import ModbusBaseSyncClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType
from pymodbus.framer.rtu import FramerRTU
from serial import SerialException

from drivers.device import RequestLink
from drivers.errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError
from drivers.pulser import registers as reg
from drivers.pulser.modbus_words import rtu_read_line_s
from drivers.pulser.urls import PulserUrl
from drivers.serial_port import SocketPort as _SocketPort

# The pulser's frames and faults are logged under the name of its driver.
log = logging.getLogger("drivers.pulser.modbus")

#: Default time one request may wait for its answer beyond what the request itself takes
#: (its frames on the line, an acquisition it makes): the link's margin, s.
DEFAULT_TIMEOUT_S = 1.0
#: Times a request that got no byte back is asked again before the device counts as silent.
DEFAULT_RETRIES = 1
#: Shortest per-request timeout used when a deadline is almost reached, s.
MIN_REQUEST_TIMEOUT_S = 0.01

#: The read function code of each table.
READ_FUNCTION = {
    "holding": reg.FunctionCode.READ_HOLDING_REGISTERS,
    "input": reg.FunctionCode.READ_INPUT_REGISTERS,
}


class _NoFrame(Exception):
    """Bytes kept arriving past a request's deadline without forming the awaited frame."""


class _Closable(Protocol):
    """What closing a pymodbus client needs (its clients' ``close()`` is unannotated)."""

    def close(self) -> None: ...


class ModbusLink(RequestLink):
    """A Modbus device's link and register map (see the module docstring).

    ``url`` says the framing and where the device is; ``timeout_s`` (s) is the link's margin
    of every request beyond what the request takes (module docstring), one asked again
    ``retries`` times (0 … 10) when nothing at all came back; ``port`` (RTU only)
    injects an already-open pyserial-compatible port. The driver sets ``_map``, its register
    map, and defines ``connect``, which a request calls first when the link is not open.
    """

    device = "pulser"
    _map: reg.RegisterMap
    _map_version: int | None

    def __init__(self, url: PulserUrl, timeout_s: float, *, retries: int, port: Any):
        self._link_to(str(url), timeout_s)
        if not (isinstance(retries, int) and 0 <= retries <= 10):
            raise ValueError(f"retries must be an integer from 0 to 10, got {retries!r}")
        if port is not None and url.framing != "rtu":
            raise ValueError("port can only be injected for modbus-rtu URLs")
        self._url = url
        self._unit = url.unit
        self._retries = retries
        self._lock = threading.RLock()
        self._rx = b""  # bytes received for the request in flight (cumulative)
        # When the request in flight must have its answer (time.monotonic() s): pymodbus
        # waits for a valid frame as long as bytes keep coming, so a peer that streams
        # anything but Modbus would hold a request forever.
        self._rx_deadline = math.inf
        self._connected = False
        self._injected_port = port
        self._client = self._make_client(url)

    def connect(self) -> None:
        """Open the link and check the device (the driver says how)."""
        raise NotImplementedError

    def _open(self) -> None:
        """Open the link; ``ConnectionLost`` when it cannot be opened."""
        self._open_port()
        if not self._client.connect():
            self._close_client()
            what = (
                f"serial device {self._url.device!r}"
                if self._url.framing == "rtu"
                else f"TCP {self._url.host}:{self._url.port}"
            )
            raise ConnectionLost(
                self.device,
                self._endpoint,
                f"cannot open {what} (refused, unreachable or no answer "
                f"within {self._timeout_s:.3g} s)",
            )

    def _close_client(self) -> None:
        """Close the pymodbus client."""
        client: _Closable = self._client
        client.close()

    def _make_client(self, url: PulserUrl) -> ModbusBaseSyncClient:
        common: dict[str, Any] = {
            "timeout": self._timeout_s,
            "retries": 0,
            "trace_packet": self._trace_packet,
            "name": "pulser",
        }
        if url.framing == "tcp":
            return ModbusTcpClient(
                url.host or "", port=url.port or 502, framer=FramerType.SOCKET, **common
            )
        return ModbusSerialClient(
            url.device or "",
            framer=FramerType.RTU,
            baudrate=url.baud,
            bytesize=8,
            parity=url.parity,
            stopbits=1,
            **common,
        )

    def _open_port(self) -> None:
        """Give the RTU client its port when pymodbus should not open it itself.

        pymodbus uses an already-set ``client.socket`` instead of calling ``serial_for_url``:
        that is how an injected port, or the faster ``socket://`` port, is handed over.
        """
        client = self._client
        if not isinstance(client, ModbusSerialClient) or client.socket is not None:
            return
        port = self._injected_port
        if port is None and (self._url.device or "").startswith("socket://"):
            port = _SocketPort(None, timeout=self._timeout_s)
            port.port = self._url.device
            try:
                port.open()
            except (SerialException, OSError) as exc:
                raise ConnectionLost(self.device, self._endpoint, f"cannot open: {exc}") from exc
        if port is not None:
            port.inter_byte_timeout = client.inter_byte_timeout or None
            client.socket = port
            client.last_frame_end = None

    # --- registers by name ------------------------------------------------------------------
    def _register(self, name: str) -> reg.Register:
        """The map's register ``name``; ``ValueError`` when the device has none."""
        r = self._map.get(name)
        if r is None:
            raise ValueError(
                f"pulser at {self._endpoint}: the register map {self._map} has no {name} register"
            )
        return r

    def _command(self, name: str) -> None:
        r = self._register("command")
        if name not in r.names:
            raise ValueError(
                f"pulser at {self._endpoint}: the register map {self._map} has no {name} command"
            )
        self._write_values([(r, r.encode(r.names[name]))], name.replace("_", " "))

    def _line_s(self, registers: int) -> float:
        """Time on the line of reading ``registers`` registers, s: over RTU at the URL's baud
        (``rtu_read_line_s``), over TCP none (a network carries them in microseconds)."""
        if self._url.framing != "rtu":
            return 0.0
        return rtu_read_line_s(registers, self._url.baud)

    def _on_device(self, r: reg.Register) -> bool:
        """Whether the connected device has ``r`` (its map version is recent enough)."""
        return r.min_version is None or (self._map_version or 0) >= r.min_version

    def _read_values(
        self,
        registers: Sequence[reg.Register],
        what: str,
        deadline: float | None = None,
        *,
        autoconnect: bool = True,
        busy_s: float = 0.0,
    ) -> dict[str, list[int]]:
        """Read ``registers`` in as few requests as the map allows; their words by name.
        ``busy_s`` (s): what the device takes before it answers (an acquisition the read
        makes), beyond the link's timeout."""
        requests = self._map.read_requests(registers)
        answers = [
            self._read(
                READ_FUNCTION[table],
                address,
                count,
                what,
                deadline,
                autoconnect=autoconnect,
                busy_s=busy_s,
            )
            for table, address, count in requests
        ]
        return self._map.pick(registers, requests, answers)

    def _values_line_s(self, registers: Sequence[reg.Register]) -> float:
        """Time on the line of reading ``registers`` (the requests ``_read_values`` makes), s."""
        return sum(self._line_s(count) for _, _, count in self._map.read_requests(registers))

    def _write_values(self, entries: Sequence[tuple[reg.Register, list[int]]], what: str) -> None:
        """Write registers and their words, neighbours in one FC 16 request."""
        for address, words in self._map.write_requests(entries):
            self._write(address, words, what)

    # --- transport --------------------------------------------------------------------------
    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """Log every frame and remember what came back (pymodbus ``trace_packet`` hook)."""
        if sending:
            self._rx = b""
            log.debug("pulser %s WRITE: %s", self._endpoint, data.hex(" "))
        else:
            self._rx = bytes(data)
            log.debug("pulser %s READ: %s", self._endpoint, data.hex(" "))
            if time.monotonic() > self._rx_deadline and not self._whole_frame(data):
                raise _NoFrame()
        return data

    def _whole_frame(self, data: bytes) -> bool:
        """Whether ``data`` is one whole frame (RTU: its CRC holds; TCP: the MBAP header's
        length counts the rest): a reply that is merely late (a loaded host, the last short
        request of a deadline) is taken as one, a stream of bytes past the deadline is not."""
        if self._url.framing == "rtu":
            return (
                len(data) >= 4 and FramerRTU.compute_CRC(data[:-2]).to_bytes(2, "big") == data[-2:]
            )
        return len(data) >= 8 and int.from_bytes(data[4:6], "big") == len(data) - 6

    def _read(
        self,
        function: reg.FunctionCode,
        address: int,
        count: int,
        what: str,
        deadline: float | None = None,
        *,
        autoconnect: bool = True,
        busy_s: float = 0.0,
    ) -> list[int]:
        """One read request; it may take its frames' time on the line and ``busy_s`` beyond
        the link's timeout."""
        if function == reg.FunctionCode.READ_HOLDING_REGISTERS:
            call: Callable[..., Any] = self._client.read_holding_registers
        else:
            call = self._client.read_input_registers
        response = self._execute(
            what,
            deadline,
            autoconnect,
            call,
            address,
            count=count,
            beyond_s=busy_s + self._line_s(count),
        )
        registers = list(response.registers)
        if len(registers) != count:
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"{what}: asked for {count} registers at 0x{address:04X}, got {len(registers)}",
            )
        return registers

    def _write(self, address: int, values: Sequence[int], what: str) -> None:
        self._execute(what, None, True, self._client.write_registers, address, list(values))

    def _execute(
        self,
        what: str,
        deadline: float | None,
        autoconnect: bool,
        call: Callable[..., Any],
        *args: Any,
        beyond_s: float = 0.0,
        **kwargs: Any,
    ) -> Any:
        """Run one request; map every pymodbus/pyserial fault to a ``drivers.errors`` type.

        The request may take ``beyond_s`` (s: its frames on the line, an acquisition) plus the
        link's timeout; ``deadline`` (``time.monotonic()`` s) shortens that; ``autoconnect``
        connects first when the pulser is not connected yet.
        """
        with self._lock:
            for attempt in range(self._retries + 1):
                if autoconnect and not self._connected:
                    self.connect()
                timeout_s = self._timeout_s + beyond_s
                if deadline is not None:
                    timeout_s = min(
                        timeout_s, max(deadline - time.monotonic(), MIN_REQUEST_TIMEOUT_S)
                    )
                try:
                    response = self._attempt(what, timeout_s, call, *args, **kwargs)
                    break
                except DeviceTimeout:
                    # Nothing came back: the request or its reply was lost. A retry on a fresh
                    # connection (no late reply of this request can then be taken for the
                    # next one's); the device is silent only when it stays silent.
                    late = deadline is not None and time.monotonic() >= deadline
                    if attempt >= self._retries or late or not autoconnect:
                        raise
                    log.warning(
                        "pulser %s: %s: no answer within %.3g s; asking again (%d of %d)",
                        self._endpoint,
                        what,
                        timeout_s,
                        attempt + 1,
                        self._retries,
                    )
                    self._lost()
            if response.isError():
                code = int(getattr(response, "exception_code", 0))
                raise DeviceError(
                    self.device,
                    self._endpoint,
                    f"{what}: Modbus exception {reg.exception_name(code)}",
                )
            return response

    def _attempt(
        self, what: str, timeout_s: float, call: Callable[..., Any], *args: Any, **kwargs: Any
    ) -> Any:
        """One request and its reply within ``timeout_s``; faults mapped as ``_execute`` says."""
        # pymodbus reads the receive timeout from comm_params on every request
        self._client.comm_params.timeout_connect = timeout_s
        self._rx = b""
        self._rx_deadline = time.monotonic() + timeout_s
        try:
            return call(*args, device_id=self._unit, **kwargs)
        except _NoFrame:
            received = self._rx
            self._lost()  # the stream is out of step: start the next request afresh
            raise ProtocolError(
                self.device,
                self._endpoint,
                f"{what}: {len(received)} bytes in {timeout_s:.3g} s and no valid Modbus "
                f"frame among them (is this a Modbus pulser?): {received[:32].hex(' ')}"
                + (" ..." if len(received) > 32 else ""),
            ) from None
        except ConnectionException as exc:
            self._lost()
            raise ConnectionLost(self.device, self._endpoint, f"{what}: {exc}") from exc
        except ModbusIOException as exc:
            if self._rx:
                raise ProtocolError(
                    self.device,
                    self._endpoint,
                    f"{what}: invalid reply (bad CRC, wrong unit or truncated frame): "
                    f"{self._rx.hex(' ')}",
                ) from exc
            raise DeviceTimeout(
                self.device, self._endpoint, f"{what}: no answer within {timeout_s:.3g} s"
            ) from exc
        except ModbusException as exc:
            raise ProtocolError(self.device, self._endpoint, f"{what}: {exc}") from exc
        except OSError as exc:  # includes serial.SerialException
            self._lost()
            raise ConnectionLost(self.device, self._endpoint, f"{what}: {exc}") from exc
        finally:
            self._client.comm_params.timeout_connect = self._timeout_s
            self._rx_deadline = math.inf

    def _lost(self) -> None:
        """Forget the connection so that the next call reconnects."""
        self._connected = False
        self._close_client()
