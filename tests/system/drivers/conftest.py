"""Fixtures for controller system tests: the simulator on 127.0.0.1 and a raw fake server."""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator

import pytest

from drivers.controller.client import SimpleMessageController
from drivers.controller.simulator import SimulatedController

# TX90 joint ranges (deg), J1..J6 (SPEC.md, "Robot models").
TX90_MIN_DEG = (-180.0, -130.0, -145.0, -270.0, -115.0, -270.0)
TX90_MAX_DEG = (180.0, 147.5, 145.0, 270.0, 140.0, 270.0)

# Short timeouts keep failing tests fast; the simulator answers in well under a millisecond.
CLIENT_TIMEOUTS = {"connect_timeout_s": 1.0, "reply_timeout_s": 1.0, "state_timeout_s": 0.5}


@pytest.fixture
def make_sim_controller() -> Iterator[Callable[..., SimulatedController]]:
    """Factory for started simulators (TX90 ranges, fast by default); all stopped at teardown."""
    sims: list[SimulatedController] = []

    def make(**kwargs: object) -> SimulatedController:
        kwargs.setdefault("time_scale", 0.01)
        kwargs.setdefault("state_rate_hz", 200.0)
        sim = SimulatedController(TX90_MIN_DEG, TX90_MAX_DEG, **kwargs)
        sims.append(sim)
        return sim.start()

    yield make
    for sim in sims:
        sim.stop()


@pytest.fixture
def sim_controller(make_sim_controller) -> SimulatedController:
    return make_sim_controller()


@pytest.fixture
def make_controller_client() -> Iterator[Callable[..., SimpleMessageController]]:
    """Factory for connected clients (short timeouts); all closed at teardown."""
    clients: list[SimpleMessageController] = []

    def make(url: str, connect: bool = True, **kwargs: float) -> SimpleMessageController:
        options = {**CLIENT_TIMEOUTS, **kwargs}
        client = SimpleMessageController.from_url(url, **options)
        clients.append(client)
        if connect:
            client.connect()
        return client

    yield make
    for client in clients:
        client.close()


@pytest.fixture
def controller_client(sim_controller, make_controller_client) -> SimpleMessageController:
    return make_controller_client(sim_controller.url)


class FakeServer:
    """Two listening sockets on 127.0.0.1 that a test drives by hand, byte by byte."""

    def __init__(self) -> None:
        self.listeners = []
        for _ in range(2):
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.bind(("127.0.0.1", 0))
            sock.listen(1)
            sock.settimeout(2.0)
            self.listeners.append(sock)
        self.conns: list[socket.socket] = []

    @property
    def url(self) -> str:
        motion, state = (s.getsockname()[1] for s in self.listeners)
        return f"tcp://127.0.0.1:{motion}?state={state}"

    def accept(self) -> tuple[socket.socket, socket.socket]:
        """The (motion, state) connections of a client that has connected."""
        conns = []
        for listener in self.listeners:
            conn, _ = listener.accept()
            conn.settimeout(2.0)
            conns.append(conn)
        self.conns += conns
        return conns[0], conns[1]

    def close(self) -> None:
        for sock in self.listeners + self.conns:
            sock.close()


@pytest.fixture
def fake_server() -> Iterator[FakeServer]:
    server = FakeServer()
    yield server
    server.close()
