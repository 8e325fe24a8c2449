"""What the simulated devices share in serving on 127.0.0.1, and the TCP server of a simulated
line-oriented instrument.

:class:`Served` is any simulator (or set of them) that serves between ``start()`` and
``stop()``, used as a context manager; :class:`ServedOnPort` one that serves on one TCP port;
:func:`accept_clients` the loop that takes every connection on a listening socket.

The simulated SCPI scope and the simulated ASCII pulser differ in what they say, not in how
they serve: both listen on a loopback port (0 picks a free one), serve each client on a thread
of its own, read its bytes as lines ended by ``terminator`` and answer each line (or not), can
be told to fall silent (a fault for tests: lines are still read and executed, never answered)
and, on :meth:`LoopbackServer.stop`, close every connection and join their threads. A subclass
gives its name (for logs and errors), its ``terminator`` and :meth:`_answer`, what one line
does; its constructor calls ``super().__init__(host, port)`` first.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import socket
import threading
from collections.abc import Callable
from typing import Any, Self

log = logging.getLogger(__name__)

#: How long stop() waits for each server thread (s).
STOP_TIMEOUT_S = 5.0
#: The only hosts a simulated instrument serves on.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


class Served(abc.ABC):
    """A simulator that serves between :meth:`start` and :meth:`stop`. Use as a context
    manager: entry starts it, exit stops it."""

    @abc.abstractmethod
    def start(self) -> Self:
        """Start serving (idempotent); return self."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop serving and close every connection. Idempotent."""

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class ServedOnPort(Served):
    """A simulator served on one TCP port (``_port``, None until started)."""

    #: What the simulator is, for logs and errors ("simulated scope").
    what = "simulated instrument"
    _port: int | None
    _lock: threading.RLock
    _silent: bool

    def set_silent(self, silent: bool = True) -> None:
        """Stop (or resume) answering: what a client sends is still received (and executed),
        the connection stays open."""
        with self._lock:
            self._silent = bool(silent)

    @property
    def port(self) -> int:
        """The TCP port served on (after :meth:`start`)."""
        if self._port is None:
            raise RuntimeError(f"the {self.what} is not running")
        return self._port


def accept_clients(
    listener: socket.socket,
    stopping: threading.Event,
    serve: Callable[[socket.socket, Any], None],
) -> None:
    """Take every connection on ``listener`` (a timeout set on it, so that ``stopping`` is
    seen) until ``stopping`` is set or the listener is closed; hand each, with Nagle's
    algorithm off, to ``serve(connection, address)``."""
    while not stopping.is_set():
        try:
            conn, address = listener.accept()
        except TimeoutError:
            continue
        except OSError:
            return  # listener closed by stop()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        serve(conn, address)


class LoopbackServer(ServedOnPort):
    """Base of a simulated instrument served on loopback (context manager). Nothing is opened
    before :meth:`start`; :attr:`port` tells the port after it."""

    #: What ends a line the client sends.
    terminator = b"\n"

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        if host not in LOOPBACK_HOSTS:
            raise ValueError(f"the {self.what} serves on loopback only, got host {host!r}")
        self.host = host
        self._requested_port = int(port)
        self._port: int | None = None
        self._lock = threading.RLock()
        self._server: socket.socket | None = None
        self._clients: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._stopping = threading.Event()
        self._silent = False

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> Self:
        """Listen and serve (idempotent); return self."""
        if self._server is not None:
            return self
        self._stopping.clear()
        server = socket.create_server((self.host, self._requested_port))
        server.settimeout(0.1)
        self._server = server
        self._port = int(server.getsockname()[1])
        name = self.what.replace(" ", "-")
        thread = threading.Thread(target=self._accept, name=name, daemon=True)
        self._threads = [thread]
        thread.start()
        log.info("%s serving on 127.0.0.1:%d", self.what, self._port)
        return self

    def stop(self) -> None:
        """Stop serving and close every connection. Idempotent."""
        if self._server is None:
            return
        self._stopping.set()
        with self._lock:
            clients, self._clients = self._clients, []
        for c in clients:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            c.close()
        for t in self._threads:
            t.join(STOP_TIMEOUT_S)
        self._server.close()
        self._server = None
        self._port = None
        self._threads = []

    # --- serving ----------------------------------------------------------------------------
    def _accept(self) -> None:
        assert self._server is not None
        accept_clients(self._server, self._stopping, self._add_client)

    def _add_client(self, client: socket.socket, address: Any) -> None:
        with self._lock:
            self._clients.append(client)
        name = f"{self.what.replace(' ', '-')}-client"
        thread = threading.Thread(target=self._serve, args=(client,), name=name, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _serve(self, client: socket.socket) -> None:
        """The conversation with one client, until it closes or the server stops: each line
        (terminator removed) to :meth:`_answer`, its answer sent unless silent."""
        buffer = b""
        try:
            while not self._stopping.is_set():
                chunk = client.recv(65536)
                if not chunk:
                    break
                buffer += self._normalise(chunk)
                while self.terminator in buffer:
                    line, buffer = buffer.split(self.terminator, 1)
                    log.debug("%s READ: %r", self.what, line)
                    answer = self._answer(line)
                    with self._lock:
                        silent = self._silent
                    if answer is not None and not silent:
                        log.debug("%s WRITE: %d bytes", self.what, len(answer))
                        client.sendall(answer)
        except OSError:
            pass
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
            client.close()

    def _normalise(self, chunk: bytes) -> bytes:
        """Received bytes as the line reader takes them (as they are, unless a subclass says)."""
        return chunk

    def _answer(self, line: bytes) -> bytes | None:
        """What one line does; its answer, or None for a line that gets none."""
        raise NotImplementedError
