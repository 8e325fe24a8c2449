"""Back-ends chosen by URL scheme through the ``ucal.pulsers``/``ucal.controllers``/
``ucal.digitizers`` entry points."""

from __future__ import annotations

import tomllib
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from drivers import registry
from drivers.controller.client import SimpleMessageController
from drivers.digitizer.base import AScanRecord, Digitizer
from drivers.digitizer.visa import ScpiScope
from drivers.pulser.ascii import AsciiScpiPulser
from drivers.pulser.base import GateReading, PulserReceiver, PulserSettings
from drivers.pulser.modbus import ModbusPulser


def test_shipped_back_ends_are_declared_as_entry_points() -> None:
    pulsers = {ep.name: ep.value for ep in entry_points(group=registry.PULSER_GROUP)}
    controllers = {ep.name: ep.value for ep in entry_points(group=registry.CONTROLLER_GROUP)}
    assert pulsers["modbus-tcp"] == "drivers.pulser.modbus:ModbusPulser"
    assert pulsers["modbus-rtu"] == "drivers.pulser.modbus:ModbusPulser"
    assert controllers["tcp"] == "drivers.controller.client:SimpleMessageController"


def test_the_shipped_digitizer_is_declared_as_an_entry_point_and_known_without_metadata() -> None:
    pyproject = tomllib.loads((Path(__file__).parents[3] / "pyproject.toml").read_text())
    declared = pyproject["project"]["entry-points"][registry.DIGITIZER_GROUP]
    assert declared == {"visa": "drivers.digitizer.visa:ScpiScope"}
    assert registry.BUILTIN[registry.DIGITIZER_GROUP] == declared


def test_open_digitizer_builds_the_visa_scope_without_connecting() -> None:
    url = "visa://TCPIP::127.0.0.1::5025::SOCKET?trigger=CHAN3"
    scope = registry.open_digitizer(url, timeout_s=0.5, full_scale_v=2.0)
    assert isinstance(scope, ScpiScope)
    assert scope.endpoint == url and scope.timeout_s == 0.5 and scope.full_scale_v == 2.0
    assert scope.trigger_source == "CHAN3" and scope.dialect is None  # nothing asked yet
    with pytest.raises(ValueError, match=r"unknown digitizer URL scheme 'gpib'.*known: visa"):
        registry.open_digitizer("gpib://0/7")


def test_the_ascii_pulser_opens_its_digitizer_through_the_registry(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(
        registry.BUILTIN[registry.DIGITIZER_GROUP], "bench", f"{__name__}:FakeDigitizer"
    )
    pulser = AsciiScpiPulser.from_url("ascii:///dev/ttyUSB0", 0.5, digitizer="bench://scope")
    assert isinstance(pulser.digitizer, FakeDigitizer)
    assert pulser.digitizer.endpoint == "bench://scope"
    assert pulser.digitizer.options == {"timeout_s": 2.0, "full_scale_v": 1.0}
    with pytest.raises(ValueError, match="unknown digitizer URL scheme 'scope'"):
        AsciiScpiPulser.from_url("ascii:///dev/ttyUSB0", digitizer="scope://1")


@pytest.mark.parametrize(
    "url", ["modbus-tcp://127.0.0.1:5020?unit=3", "modbus-rtu://socket://127.0.0.1:5021?unit=1"]
)
def test_open_pulser_builds_the_modbus_driver_without_connecting(url: str) -> None:
    pulser = registry.open_pulser(url, timeout_s=0.5)
    assert isinstance(pulser, ModbusPulser)
    assert pulser.endpoint == url
    assert pulser.timeout_s == 0.5


def test_open_controller_builds_the_simple_message_client() -> None:
    controller = registry.open_controller("tcp://127.0.0.1:11000?state=11002")
    assert isinstance(controller, SimpleMessageController)
    assert controller.endpoint == "tcp://127.0.0.1:11000?state=11002"


def test_unknown_scheme_names_it_and_lists_the_known_ones() -> None:
    with pytest.raises(
        ValueError,
        match=r"unknown pulser URL scheme 'gpib'.*modbus-rtu, "
        r"modbus-tcp",
    ):
        registry.open_pulser("gpib://0/3")
    with pytest.raises(ValueError, match=r"unknown controller URL scheme 'udp'.*known: tcp"):
        registry.open_controller("udp://10.0.0.1:11000")


def test_url_without_scheme_is_refused() -> None:
    with pytest.raises(ValueError, match="not a pulser URL"):
        registry.open_pulser("127.0.0.1:502")


def test_malformed_url_of_a_known_scheme_raises_value_error() -> None:
    with pytest.raises(ValueError, match="port"):
        registry.open_pulser("modbus-tcp://127.0.0.1:99999")


def test_a_back_end_declared_by_another_package_is_used(monkeypatch: pytest.MonkeyPatch) -> None:
    class FakeEntryPoint:
        name = "fake"
        value = f"{__name__}:FakePulser"

    real = registry.entry_points

    def fake_entry_points(group: str):  # type: ignore[no-untyped-def]
        found = list(real(group=group))
        return found + [FakeEntryPoint()] if group == registry.PULSER_GROUP else found

    monkeypatch.setattr(registry, "entry_points", fake_entry_points)
    pulser = registry.open_pulser("fake://bench", answer=42)
    assert isinstance(pulser, FakePulser)
    assert pulser.endpoint == "fake://bench" and pulser.answer == 42


def test_a_back_end_that_builds_something_else_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.BUILTIN[registry.PULSER_GROUP], "odd", "builtins:str")
    with pytest.raises(TypeError, match="not a PulserReceiver"):
        registry.open_pulser("odd://x")


class Bench:
    """What a third-party back-end needs to be built from its URL and not connect: the URL,
    the options it was given."""

    def __init__(self, url: str, **options: float):
        self._url = url
        self.options = options

    @classmethod
    def from_url(cls, url: str, **options: float) -> Bench:
        return cls(url, **options)

    @property
    def endpoint(self) -> str:
        return self._url

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass


class FakePulser(Bench, PulserReceiver):
    """A minimal pulser back-end as a third-party package would write it."""

    @property
    def answer(self) -> float:
        return self.options.get("answer", 0)

    def configure(self, settings: PulserSettings) -> None:
        pass

    def settings(self) -> PulserSettings:
        return PulserSettings()

    def read_gate(self, fresh: bool = True, timeout_s: float = 1.0) -> GateReading:
        return GateReading(0.0, float("nan"), 0, 0.0, 0.0)


class FakeDigitizer(Bench, Digitizer):
    """A digitiser back-end as a third-party package would write it."""

    def configure(self, start_ns: float, width_ns: float, averages: int) -> None:
        pass

    def acquire(self, timeout_s: float | None = None, acquisition_s: float = 0.0) -> AScanRecord:
        raise NotImplementedError
