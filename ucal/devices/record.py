"""Record a run as it happens: its measurements and its device traffic; replay either.

Capture and solve meet in one file, as ROS robot_calibration's capture and calibrate programs
meet in a bag. ``--record FILE`` writes JSON lines, each one object with a ``"kind"``:

1. ``"header"`` (first): ``{"kind": "header", "record": "ucal", "version": 2, "command", "ucal",
   "profile_path", "profile_sha256", "profile_text", "cell", "options", "plan", "planned",
   "started_utc"}`` — the profile as it was (text and SHA-256), what the run was asked
   (method, level, beam, points), its plan in rows to read (``plan``) and whole, tagged, for
   a replay (``planned``); a job may add keys (check's reference, what verify read from the
   profile's history);
2. ``"call"``: one line per call the procedure made to a device, in order, as it is made:
   ``{"kind": "call", "n": i, "call": "controller.start_move", "args": [...], "result": ...}``
   (or ``"error"`` for a call that raised) — joint readings, controller status, moves, the
   pulser's settings and every reading, and every clock reading the procedure took;
3. ``"measurement"``: the run's measurements as the solver receives them, written when the
   measure step ends (``measurement_lines``): one line per face, point, peak or edge
   measurement (``"of"``: which list it belongs to, ``"value"``: the tagged dataclass), then
   one ``"of": "run"`` line with the rest (counters, estimates) and one ``"of": "session"``
   line (the run's duration on the cell's clock, how the echoes were timed). They are written
   at the end of the step, not as each is taken, because the measuring code re-fits its
   earlier peaks with the kinematics it has learnt by then: what the solver receives exists
   only once the step ends. A run killed before keeps its traffic only;
4. ``"result"`` (last): ``{"kind": "result", "result": {...}}``, the run's result.

Every line is flushed when written, so a run killed mid-way leaves every reading taken before
the kill (``read_record`` accepts a file without result line and a truncated last line).

``--replay FILE`` rebuilds the run's profile from the header and solves the measurement lines
again: no search, no device, and a change to the measuring code since leaves the record
replayable. ``--replay FILE --remeasure`` serves the recorded traffic to the same procedure
in the same order (``ReplayController``, ``ReplayPulser``): the search, the face fits and the
solver run again offline, bit for bit. A procedure that asks for something other than what was
recorded (another target, more readings) stops with ``RecordError`` naming the call. Version 1
records (no ``"kind"``: a header, call lines, an ``{"end": ...}`` line) are still read; they
have no measurement lines, so they replay by remeasuring.

Values are tagged so they come back as they went: arrays ``{"nd": [...]}`` (with ``"dtype"``
and ``"shape"`` where a list alone would not say them), tuples ``{"t": [...]}``, non-finite
floats ``{"f": "nan"}``, dataclasses ``{"dc": "GateReading", "v": {...}}`` (the drivers') or
``{"dc": "ucal.model.geometry:FaceMeasurement", "v": {...}}`` (ucal's, every init field by
``dataclasses.fields``, so a field added later round-trips unchanged; a class moved to another
module since is found by its name among those the replaying command has loaded). Python's float
repr round-trips exactly, so replayed numbers are the recorded ones to the bit.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import importlib
import json
import logging
import math
import sys
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
from ucal.files import jsonable

log = logging.getLogger(__name__)

RECORD_VERSION = 2
#: Versions ``read_record`` reads (1: traffic only, no ``"kind"``).
READ_VERSIONS = (1, 2)
#: The kinds of line of a version 2 record.
HEADER, CALL, MEASUREMENT, RESULT = "header", "call", "measurement", "result"
_DATACLASSES = {c.__name__: c for c in (GateReading, ControllerStatus, JointSample, PulserSettings)}
#: Fields of a measurement that a record's measurement lines leave out, where declared
#: ``compare=False`` (no part of the measurement's value): what the search keeps to re-fit its
#: peaks without motion (``FaceMeasurement.probes``), bulky, and read by no solver (the re-fit
#: is the measure step's). Every other field is kept, whatever it is.
SEARCH_ONLY = frozenset({"probes"})
#: Packages whose dataclasses a record may name (``module:Qualname``) and a replay rebuild.
_PACKAGES = ("ucal.", "drivers.")
#: Device calls that are recorded (anything else is passed through unrecorded: attributes).
CONTROLLER_CALLS = frozenset(
    {"read_joints", "status", "start_move", "wait_settled", "move_joints", "joint_samples", "stop"}
)
#: Pulser calls of a back-end that has them (the A-scan of ``check``'s echo band): a replay
#: offers one only where the record holds it, as the recorded pulser did.
OPTIONAL_PULSER_CALLS = frozenset({"read_ascan_trace", "read_ascan"})
PULSER_CALLS = frozenset({"configure", "settings", "read_gate"}) | OPTIONAL_PULSER_CALLS


class RecordError(InputError):
    """A record file that cannot be read, or a replay that leaves the recorded run."""


# -- values ---------------------------------------------------------------------------------------


def encode(value: Any, *, measurement: bool = False) -> Any:
    """A JSON-able, tagged form of ``value`` (see the module docstring).

    ``measurement``: leave out the ``compare=False`` fields named in ``SEARCH_ONLY``."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else {"f": repr(v)}
    if isinstance(value, np.ndarray):
        tagged: dict[str, Any] = {"nd": [encode(v) for v in value.tolist()]}
        if value.dtype != np.float64:
            tagged["dtype"] = value.dtype.str
        if value.size == 0:
            tagged["shape"] = list(value.shape)
        return tagged
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _encode_dataclass(value, measurement)
    if isinstance(value, tuple):
        return {"t": [encode(v, measurement=measurement) for v in value]}
    if isinstance(value, list):
        return [encode(v, measurement=measurement) for v in value]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {"map": {k: encode(v, measurement=measurement) for k, v in value.items()}}
    raise TypeError(f"cannot record a {type(value).__name__}")


def _encode_dataclass(value: Any, measurement: bool) -> dict[str, Any]:
    cls = type(value)
    name = cls.__name__
    if _DATACLASSES.get(name) is not cls:
        name = f"{cls.__module__}:{cls.__qualname__}"
        if not cls.__module__.startswith(_PACKAGES):
            raise TypeError(f"cannot record a {name}")
    fields = [
        f
        for f in dataclasses.fields(value)
        if f.init and not (measurement and f.name in SEARCH_ONLY and not f.compare)
    ]
    return {
        "dc": name,
        "v": {f.name: encode(getattr(value, f.name), measurement=measurement) for f in fields},
    }


def decode(value: Any) -> Any:
    """The value ``encode`` tagged."""
    if isinstance(value, list):
        return [decode(v) for v in value]
    if isinstance(value, dict):
        if "f" in value:
            return float(value["f"])
        if "nd" in value:
            array = np.array(decode(value["nd"]), dtype=np.dtype(value.get("dtype", "<f8")))
            return array.reshape(value["shape"]) if "shape" in value else array
        if "t" in value and len(value) == 1:
            return tuple(decode(v) for v in value["t"])
        if "dc" in value:
            cls = dataclass_named(str(value["dc"]))
            fields = {k: decode(v) for k, v in value["v"].items()}
            try:
                return cls(**fields)
            except TypeError as e:  # a field added without a default, or removed, since
                raise RecordError(f"a record's {value['dc']} is not this ucal's ({e})") from None
        if "map" in value and len(value) == 1:
            return {k: decode(v) for k, v in value["map"].items()}
        return {k: decode(v) for k, v in value.items()}
    return value


def dataclass_named(name: str) -> type:
    """The dataclass a record names: a driver's by its name, ucal's as ``module:Qualname``
    (only within ``_PACKAGES``: a record imports no other code)."""
    if name in _DATACLASSES:
        return _DATACLASSES[name]
    module, _, qualname = name.partition(":")
    if not module.startswith(_PACKAGES) or not qualname:
        raise RecordError(f"a record names {name!r}, which is no ucal dataclass")
    try:
        obj: Any = _attribute(importlib.import_module(module), qualname)
    except (ImportError, AttributeError):
        obj = _moved(qualname)
        if obj is None:
            raise RecordError(f"a record names {name!r}, which this ucal does not have") from None
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise RecordError(f"a record names {name!r}, which is no dataclass")
    return obj


def _attribute(obj: Any, qualname: str) -> Any:
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _moved(qualname: str) -> type | None:
    """The one dataclass of this name in the ucal modules loaded (the replaying command's):
    a class that moved to another module since the run was recorded."""
    found = set()
    for module_name, module in list(sys.modules.items()):
        if module is None or not module_name.startswith(_PACKAGES):
            continue
        try:
            obj = _attribute(module, qualname)
        except AttributeError:
            continue
        if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__qualname__ == qualname:
            found.add(obj)
    return found.pop() if len(found) == 1 else None


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
                "kind": HEADER,
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
        line: dict[str, Any] = {
            "kind": CALL,
            "n": self._n,
            "call": name,
            "args": encode(list(args)),
        }
        if kwargs:
            line["kwargs"] = {k: encode(v) for k, v in sorted(kwargs.items())}
        self._n += 1
        if error is None:
            line["result"] = encode(result)
        else:
            line["error"] = {"type": type(error).__name__, "message": str(error)}
        self._write(line)

    def measurements(self, lines: list[dict[str, Any]]) -> None:
        """Write the run's measurement lines (``measurement_lines``)."""
        for line in lines:
            self._write({"kind": MEASUREMENT, **line})

    def end(self, result: dict[str, Any]) -> None:
        """Write the result line with the run's result."""
        self._write({"kind": RESULT, "result": plain_json(result)})

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def plain_json(obj: Any) -> Any:
    """``obj`` as plain JSON values (numpy values converted; NaN refused)."""
    return json.loads(json.dumps(obj, default=jsonable, allow_nan=False))


class _DeviceCalls:
    """The calls of a device a record holds, each under the label ``device.call``."""

    _prefix = ""
    _calls: frozenset[str] = frozenset()

    def _label(self, name: str) -> str | None:
        """The record's label of the call ``name`` (None: a call the record does not hold)."""
        return f"{self._prefix}.{name}" if name in self._calls else None


class _RecordingProxy(_DeviceCalls):
    """A device whose recorded calls go to a ``Recorder``; everything else passes through."""

    def __init__(self, inner: Any, recorder: Recorder):
        self._inner = inner
        self._recorder = recorder

    def __getattr__(self, name: str) -> Any:
        attr, label = getattr(self._inner, name), self._label(name)
        if label is None or not callable(attr):
            return attr
        recorder = self._recorder

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


# -- measurement lines ----------------------------------------------------------------------------

#: ``"of"`` of the measurement line holding a measured dataclass's fields that are no list.
RUN = "run"
#: ``"of"`` of the measurement line the procedure adds: duration, echo timing.
SESSION = "session"


def measurement_lines(data: Any, given: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """The measurement lines of a measure step's dataclass ``data``: one per element of each of
    its list or tuple fields (``{"of": field, "value": element}``), then one ``"of": "run"`` line
    with its type, its other fields and how many elements each list has (so that a record
    missing a line is told from one that measured less). ``given``: fields the job rebuilds
    itself on replay (the plan), not written."""
    if not (dataclasses.is_dataclass(data) and not isinstance(data, type)):
        raise TypeError(f"cannot record a {type(data).__name__} as measurements")
    lines: list[dict[str, Any]] = []
    rest: dict[str, Any] = {}
    sequences: dict[str, list[Any]] = {}
    for f in dataclasses.fields(data):
        if not f.init or f.name in given:
            continue
        value = getattr(data, f.name)
        if isinstance(value, (list, tuple)):
            kind = "tuple" if isinstance(value, tuple) else "list"
            sequences[f.name] = [kind, len(value)]
            lines += [{"of": f.name, "value": encode(v, measurement=True)} for v in value]
        else:
            rest[f.name] = encode(value, measurement=True)
    run = _encode_dataclass(data, measurement=True)["dc"]
    return [*lines, {"of": RUN, "type": run, "fields": rest, "sequences": sequences}]


def measured_from_lines(
    lines: list[dict[str, Any]], source: str = "the record", **given: Any
) -> Any:
    """The measured dataclass ``measurement_lines`` wrote (``given``: the fields it left out).
    ``RecordError`` if a line is missing or the record has none."""
    runs = [line for line in lines if line.get("of") == RUN]
    if not runs:
        raise RecordError(f"{source}: no measurement lines (the run was cut off before its end)")
    run = runs[-1]
    fields = {k: decode(v) for k, v in run["fields"].items()}
    for name, (kind, count) in run["sequences"].items():
        values = [decode(line["value"]) for line in lines if line.get("of") == name]
        if len(values) != count:
            raise RecordError(
                f"{source}: {len(values)} measurement lines of {name!r}, the run measured "
                f"{count}: the record is incomplete"
            )
        fields[name] = tuple(values) if kind == "tuple" else values
    try:
        return dataclass_named(str(run["type"]))(**fields, **given)
    except TypeError as e:  # a field added without a default, or removed, since the run
        raise RecordError(f"{source}: its measurements are not this ucal's ({e})") from None


# -- replay ---------------------------------------------------------------------------------------


@dataclasses.dataclass
class Record:
    """A record file read back: header, calls in order, measurement lines, the result line's
    result (if any)."""

    path: Path
    header: dict[str, Any]
    calls: list[dict[str, Any]]
    result: dict[str, Any] | None
    measurements: list[dict[str, Any]] = dataclasses.field(default_factory=list)

    @property
    def version(self) -> int:
        return int(self.header.get("version", RECORD_VERSION))

    @property
    def command(self) -> str:
        return str(self.header.get("command", "calibrate"))

    @property
    def measured(self) -> bool:
        """Whether the record holds the run's measurements (a run's end: the ``"run"`` line)."""
        return any(line.get("of") == RUN for line in self.measurements)

    def session(self) -> dict[str, Any]:
        """The ``"session"`` measurement line (empty if none)."""
        lines = [line for line in self.measurements if line.get("of") == SESSION]
        return dict(lines[-1]) if lines else {}

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
    if header.get("version") not in READ_VERSIONS:
        raise RecordError(
            f"{p}: record version {header.get('version')!r}; this ucal reads versions "
            + ", ".join(map(str, READ_VERSIONS))
        )
    if sha256_text(str(header.get("profile_text", ""))) != header.get("profile_sha256"):
        raise RecordError(f"{p}: the recorded profile does not match its SHA-256")
    if header["version"] == 1:  # traffic and an end line, no kinds
        calls = [o for o in objs[1:] if "call" in o]
        ends = [o["end"] for o in objs[1:] if "end" in o]
        return Record(p, header, calls, ends[-1] if ends else None)
    for i, o in enumerate(objs[1:], start=2):
        if o.get("kind") not in (CALL, MEASUREMENT, RESULT):
            raise RecordError(f"{p}: line {i} is of no kind a record has ({o.get('kind')!r})")
    calls = [o for o in objs[1:] if o["kind"] == CALL]
    measurements = [o for o in objs[1:] if o["kind"] == MEASUREMENT]
    results = [o["result"] for o in objs[1:] if o["kind"] == RESULT]
    return Record(p, header, calls, results[-1] if results else None, measurements)


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
    if err.get("type") == "ValueError":  # a back-end refusing a request (no A-scan register)
        return ValueError(err["message"])
    return RecordError(f"replayed fault: {err.get('message')}")


class ReplayClock:
    """The recorded clock readings, in order."""

    def __init__(self, replay: Replay):
        self._replay = replay

    def now(self) -> float:
        return float(self._replay.next("clock.now", ()))

    def sleep(self, seconds: float) -> None:
        """Nothing to wait for: the next recorded reading says what time it was."""


class _ReplayDevice(_DeviceCalls):
    def __init__(self, replay: Replay, endpoint: str):
        self._replay = replay
        self.endpoint = endpoint

    def __getattr__(self, name: str) -> Any:
        label = self._label(name)
        if label is None:
            raise AttributeError(name)
        replay = self._replay
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

    def __getattr__(self, name: str) -> Any:
        if name in OPTIONAL_PULSER_CALLS and not any(
            c["call"] == f"pulser.{name}" for c in self._replay.record.calls
        ):
            raise AttributeError(name)  # the recorded pulser had none, or was never asked
        return super().__getattr__(name)
