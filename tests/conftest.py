"""Test tiers: unit (no processes), system (loopback simulators), hardware (a real cell).

Hardware tests run only when the cell's addresses are given, e.g.
``pytest tests/hardware --controller-url tcp://10.0.0.5:11000 --pulser-url modbus-tcp://10.0.0.6:502``.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest
from hypothesis import settings

import ucal  # noqa: F401  (its one BLAS thread, set before numpy loads)

# No test depends on the machine's speed: hypothesis's per-example deadline (200 ms) would
# fail a test on a loaded machine for nothing it checks.
settings.register_profile("ucal", deadline=None)
settings.load_profile("ucal")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests marked ``long`` first, the rest in their order: the workers share the rest
    out while the long ones run, instead of one worker running a long one after the others
    are done. Under xdist each worker starts with an equal contiguous share of the collection
    (``--dist worksteal``; the idle ones then take the tail of the busiest's), so the long
    tests are dealt out in turn to the head of each share, not all given to the first."""
    long = [item for item in items if item.get_closest_marker("long") is not None]
    rest = [item for item in items if item.get_closest_marker("long") is None]
    workers = int(getattr(config, "workerinput", {}).get("workercount", 1))
    if workers < 2:
        items[:] = long + rest
        return
    ordered: list[pytest.Item] = []
    pending = len(items)
    for k in range(workers):
        share = pending // (workers - k)  # as worksteal splits the collection
        pending -= share
        head = long[k::workers][:share]
        ordered += head
        ordered += rest[: share - len(head)]
        del rest[: share - len(head)]
    items[:] = ordered + rest + [item for item in long if item not in ordered]


@pytest.fixture(autouse=True)
def no_signal_received(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each test starts with no signal recorded and the run not holding a result
    (``ucal.interrupt``'s module state, which in-process runs of the command line share)."""
    from ucal import interrupt

    monkeypatch.setattr(interrupt, "received", [])
    monkeypatch.setattr(interrupt, "_armed", False)
    monkeypatch.setattr(interrupt, "_held", False)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--controller-url", default=None, help="URL of a real robot controller")
    parser.addoption("--pulser-url", default=None, help="URL of a real pulser-receiver")


@pytest.fixture
def controller_url(request: pytest.FixtureRequest) -> str:
    url = request.config.getoption("--controller-url")
    if not url:
        pytest.skip("hardware test: give --controller-url")
    return url


@pytest.fixture
def pulser_url(request: pytest.FixtureRequest) -> str:
    url = request.config.getoption("--pulser-url")
    if not url:
        pytest.skip("hardware test: give --pulser-url")
    return url


@pytest.fixture
def run_main(capsys: pytest.CaptureFixture[str]) -> Callable[[list[str]], tuple[int, str, str]]:
    """Run ``ucal ARGS`` in this process: ``(exit code, stdout, stderr)``."""
    from doubles import exit_code

    def run(args: list[str]) -> tuple[int, str, str]:
        code = exit_code(args)  # the root logger's level put back after
        out, err = capsys.readouterr()
        return code, out, err

    return run
