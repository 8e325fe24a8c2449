"""A simulated instrument's TCP server on 127.0.0.1: listen, accept, one thread a client, stop.

The simulated SCPI scope and the simulated ASCII pulser differ in what they say, not in how
they serve: both listen on a loopback port (0 picks a free one), serve each client on a thread
of its own and, on :meth:`LoopbackServer.stop`, close every connection and join their threads.
A subclass gives its name (for logs and errors) and :meth:`_serve`, the conversation with one
client; its constructor calls ``super().__init__(host, port)`` first.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
from typing import Self

log = logging.getLogger(__name__)

#: How long stop() waits for each server thread (s).
STOP_TIMEOUT_S = 5.0
#: The only hosts a simulated instrument serves on.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


class LoopbackServer:
    """Base of a simulated instrument served on loopback (context manager). Nothing is opened
    before :meth:`start`; :attr:`port` tells the port after it."""

    #: What the instrument is, for logs and errors ("simulated scope").
    what = "simulated instrument"

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

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def port(self) -> int:
        """The TCP port served on (after :meth:`start`)."""
        if self._port is None:
            raise RuntimeError(f"the {self.what} is not running")
        return self._port

    # --- serving ----------------------------------------------------------------------------
    def _accept(self) -> None:
        assert self._server is not None
        server = self._server
        while not self._stopping.is_set():
            try:
                client, _ = server.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._clients.append(client)
            name = f"{self.what.replace(' ', '-')}-client"
            thread = threading.Thread(target=self._serve, args=(client,), name=name, daemon=True)
            self._threads.append(thread)
            thread.start()

    def _serve(self, client: socket.socket) -> None:
        """The conversation with one client, until it closes or the server stops."""
        raise NotImplementedError
