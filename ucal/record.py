"""Record a run's raw device traffic as it happens; replay it to solve again without a robot.

Capture and solve meet in one file, as ROS robot_calibration's capture and calibrate programs
meet in a bag. ``--record FILE`` writes JSON lines:

1. a header: ``{"record": "ucal", "version": 1, "command", "ucal", "profile_path",
   "profile_sha256", "profile_text", "cell", "options", "plan", "started_utc"}`` — the profile
   as it was (text and SHA-256), what the run was asked (method, level, beam) and its plan;
2. one line per call the procedure made to a device, in order: ``{"n": i, "call":
   "controller.start_move", "args": [...], "result": ...}`` (or ``"error"`` for a call that
   raised) — joint readings, controller status, moves, the pulser's settings (gain) and every
   reading (amplitude, TOF, counter, device and host time), and every clock reading the
   procedure took (``clock.now``: pairing readings with streamed joints needs them);
3. an end line ``{"end": {...}}`` with the run's result, once it has one.

Every line is flushed when written, so a run killed mid-way leaves every reading taken before
the kill (``read_record`` accepts a file without end line and a truncated last line).

``--replay FILE`` rebuilds the run's profile from the header and serves the recorded results
to the same procedure in the same order (``ReplayController``, ``ReplayPulser``): the search,
the face fits and the solver run again offline, bit for bit, with any method. A procedure that
asks for something other than what was recorded (another target, more readings) stops with
``RecordError`` naming the call: the recording does not cover it.

Values are tagged so they come back as they went: arrays ``{"nd": [...]}``, non-finite floats
``{"f": "nan"}``, the drivers' dataclasses ``{"dc": "GateReading", "v": {...}}``. Python's
float repr round-trips exactly, so replayed numbers are the recorded ones to the bit.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import logging
import math
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, Self

import numpy as np

from drivers import errors as driver_errors
from drivers.clock import Clock
from drivers.controller.base import ControllerStatus, JointSample
from drivers.pulser.base import GateReading, PulserSettings
from ucal.errors import InputError

log = logging.getLogger(__name__)

RECORD_VERSION = 1
_DATACLASSES = {c.__name__: c for c in (GateReading, ControllerStatus, JointSample, PulserSettings)}
#: Device calls that are recorded (anything else is passed through unrecorded: attributes).
CONTROLLER_CALLS = frozenset(
    {"read_joints", "status", "start_move", "wait_settled", "move_joints", "joint_samples", "stop"}
)
PULSER_CALLS = frozenset({"configure", "settings", "read_gate"})


class RecordError(InputError):
    """A record file that cannot be read, or a replay that leaves the recorded run."""


# -- values ---------------------------------------------------------------------------------------


def encode(value: Any) -> Any:
    """A JSON-able, tagged form of ``value`` (see the module docstring)."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else {"f": repr(v)}
    if isinstance(value, np.ndarray):
        return {"nd": [encode(v) for v in value.tolist()]}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = type(value).__name__
        if name not in _DATACLASSES:
            raise TypeError(f"cannot record a {name}")
        return {
            "dc": name,
            "v": {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)},
        }
    if isinstance(value, (list, tuple)):
        return [encode(v) for v in value]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {"map": {k: encode(v) for k, v in value.items()}}
    raise TypeError(f"cannot record a {type(value).__name__}")


def decode(value: Any) -> Any:
    """The value ``encode`` tagged."""
    if isinstance(value, list):
        return [decode(v) for v in value]
    if isinstance(value, dict):
        if "f" in value:
            return float(value["f"])
        if "nd" in value:
            return np.array(decode(value["nd"]), dtype=float)
        if "dc" in value:
            cls = _DATACLASSES[value["dc"]]
            return cls(**{k: decode(v) for k, v in value["v"].items()})
        if "map" in value and len(value) == 1:
            return {k: decode(v) for k, v in value["map"].items()}
        return {k: decode(v) for k, v in value.items()}
    return value


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


# -- recording ------------------------------------------------------------------------------------


class Recorder:
    """Append-only JSON-lines writer, flushed line by line (a context manager)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._file: IO[str] | None = None
        self._lock = threading.Lock()
        self._n = 0

    def open(self, header: dict[str, Any]) -> Self:
        """Create the file (replacing one that is there) and write the header."""
        try:
            self._file = open(self.path, "w", encoding="utf-8")  # noqa: SIM115 — closed by close()
        except OSError as e:
            raise InputError(f"{self.path}: cannot write the record: {e.strerror or e}") from None
        self._write(
            {
                "record": "ucal",
                "version": RECORD_VERSION,
                **header,
                "started_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            }
        )
        return self

    def _write(self, obj: dict[str, Any]) -> None:
        with self._lock:
            if self._file is None:
                return
            self._file.write(json.dumps(obj, allow_nan=False) + "\n")
            self._file.flush()

    def call(
        self,
        name: str,
        args: tuple[Any, ...],
        result: Any = None,
        error: BaseException | None = None,
        kwargs: dict[str, Any] | None = None,
    ) -> None:
        """Record one device call: its arguments and its result or error."""
        line: dict[str, Any] = {"n": self._n, "call": name, "args": encode(list(args))}
        if kwargs:
            line["kwargs"] = {k: encode(v) for k, v in sorted(kwargs.items())}
        self._n += 1
        if error is None:
            line["result"] = encode(result)
        else:
            line["error"] = {"type": type(error).__name__, "message": str(error)}
        self._write(line)

    def end(self, result: dict[str, Any]) -> None:
        """Write the end line with the run's result."""
        self._write({"end": json.loads(json.dumps(result, default=jsonable, allow_nan=False))})

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def jsonable(value: Any) -> Any:
    """``json.dumps`` default for numpy values (anything else by its repr)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return repr(value)


class _RecordingProxy:
    """A device whose recorded calls go to a ``Recorder``; everything else passes through."""

    _prefix = ""
    _calls: frozenset[str] = frozenset()

    def __init__(self, inner: Any, recorder: Recorder):
        self._inner = inner
        self._recorder = recorder

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._inner, name)
        if name not in self._calls or not callable(attr):
            return attr
        recorder, label = self._recorder, f"{self._prefix}.{name}"

        def recorded(*args: Any, **kwargs: Any) -> Any:
            try:
                result = attr(*args, **kwargs)
            except Exception as e:
                recorder.call(label, args, error=e, kwargs=kwargs)
                raise
            recorder.call(label, args, result, kwargs=kwargs)
            return result

        return recorded

    def __enter__(self) -> Any:
        self._inner.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._inner.__exit__(*exc)


class RecordingClock:
    """The procedure's clock readings, recorded."""

    def __init__(self, inner: Clock, recorder: Recorder):
        self._inner = inner
        self._recorder = recorder

    def now(self) -> float:
        t = self._inner.now()
        self._recorder.call("clock.now", (), t)
        return t

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class RecordingController(_RecordingProxy):
    _prefix = "controller"
    _calls = CONTROLLER_CALLS

    def __init__(self, inner: Any, recorder: Recorder):
        super().__init__(inner, recorder)
        self.clock = RecordingClock(inner.clock, recorder)


class RecordingPulser(_RecordingProxy):
    _prefix = "pulser"
    _calls = PULSER_CALLS


# -- replay ---------------------------------------------------------------------------------------


@dataclasses.dataclass
class Record:
    """A record file read back: header, calls in order, the end line's result (if any)."""

    path: Path
    header: dict[str, Any]
    calls: list[dict[str, Any]]
    result: dict[str, Any] | None

    @property
    def profile_text(self) -> str:
        return str(self.header["profile_text"])

    @property
    def options(self) -> dict[str, Any]:
        return dict(self.header.get("options", {}))


def read_record(path: str | Path) -> Record:
    """Read a record file; a truncated last line (a run killed mid-write) is dropped."""
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise RecordError(f"{p}: cannot read the record: {e.strerror or e}") from None
    objs: list[dict[str, Any]] = []
    for i, line in enumerate(lines):
        try:
            objs.append(json.loads(line))
        except json.JSONDecodeError:
            if i == len(lines) - 1:
                log.warning("%s: last line truncated (the run was cut off); ignored", p)
                break
            raise RecordError(f"{p}: line {i + 1} is not JSON") from None
    if not objs or objs[0].get("record") != "ucal":
        raise RecordError(f"{p}: not a ucal record (no header line)")
    header = objs[0]
    if header.get("version") != RECORD_VERSION:
        raise RecordError(f"{p}: record version {header.get('version')!r} is not {RECORD_VERSION}")
    if sha256_text(str(header.get("profile_text", ""))) != header.get("profile_sha256"):
        raise RecordError(f"{p}: the recorded profile does not match its SHA-256")
    calls = [o for o in objs[1:] if "call" in o]
    ends = [o["end"] for o in objs[1:] if "end" in o]
    return Record(p, header, calls, ends[-1] if ends else None)


class Replay:
    """The recorded calls, served in order to the replay devices."""

    def __init__(self, record: Record):
        self.record = record
        self._calls: Iterator[dict[str, Any]] = iter(record.calls)
        self.served = 0

    def next(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any] | None = None) -> Any:
        """The recorded result of the next call, which must be ``name`` with these arguments."""
        try:
            line = next(self._calls)
        except StopIteration:
            raise RecordError(
                f"{self.record.path}: the recording ends before {name} (call "
                f"{self.served + 1}): the run was cut off there"
            ) from None
        self.served += 1
        recorded_kwargs = decode(line.get("kwargs", {}))
        if (
            line["call"] != name
            or not _same(decode(line["args"]), list(args))
            or sorted(recorded_kwargs) != sorted(kwargs or {})
            or not all(_same(recorded_kwargs[k], v) for k, v in (kwargs or {}).items())
        ):
            raise RecordError(
                f"{self.record.path}: call {self.served} was {line['call']}"
                f"{_brief(line['args'])}, the replay asks {name}{_brief(args)}: "
                "the recording does not cover this run"
            )
        if "error" in line:
            raise _replayed_error(line["error"])
        return decode(line["result"])


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple, np.ndarray)) and isinstance(b, (list, tuple, np.ndarray)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float) or isinstance(a, np.floating):
        return bool(float(a) == float(b) or (math.isnan(float(a)) and math.isnan(float(b))))
    return bool(a == b)


def _brief(args: Any) -> str:
    text = json.dumps(encode(list(args)) if not isinstance(args, list) else args)
    return f"({text[:80]}{'…' if len(text) > 80 else ''})"


def _replayed_error(err: dict[str, str]) -> Exception:
    cls = getattr(driver_errors, err.get("type", ""), None)
    if isinstance(cls, type) and issubclass(cls, driver_errors.DriverError):
        e = cls.__new__(cls)
        Exception.__init__(e, err["message"])
        return e
    return RecordError(f"replayed fault: {err.get('message')}")


class ReplayClock:
    """The recorded clock readings, in order."""

    def __init__(self, replay: Replay):
        self._replay = replay

    def now(self) -> float:
        return float(self._replay.next("clock.now", ()))

    def sleep(self, seconds: float) -> None:
        """Nothing to wait for: the next recorded reading says what time it was."""


class _ReplayDevice:
    _prefix = ""
    _calls: frozenset[str] = frozenset()

    def __init__(self, replay: Replay, endpoint: str):
        self._replay = replay
        self.endpoint = endpoint

    def __getattr__(self, name: str) -> Any:
        if name not in self._calls:
            raise AttributeError(name)
        replay, label = self._replay, f"{self._prefix}.{name}"
        return lambda *args, **kwargs: replay.next(label, args, kwargs)

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class ReplayController(_ReplayDevice):
    """A controller that answers with the recorded results."""

    device = "controller"
    _prefix = "controller"
    _calls = CONTROLLER_CALLS

    def __init__(self, replay: Replay, endpoint: str):
        super().__init__(replay, endpoint)
        self.clock = ReplayClock(replay)


class ReplayPulser(_ReplayDevice):
    """A pulser that answers with the recorded results."""

    device = "pulser"
    _prefix = "pulser"
    _calls = PULSER_CALLS
