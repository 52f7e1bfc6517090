"""Errors raised by the ftafm client."""

from __future__ import annotations

from typing import Any


class InstrumentError(Exception):
    """The daemon refused a request.

    ``code`` is the protocol's stable error code (``"invalid_value"``, ``"unknown_path"``,
    ``"read_only"``, ``"no_data"``, ...; docs/protocol.md lists them) and ``message`` the
    daemon's sentence, which names the node, the value and what is allowed.
    """

    def __init__(self, code: str, message: str, request: dict[str, Any] | None = None):
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.request = request or {}


class ConnectionLost(InstrumentError):
    """The connection to the daemon closed while a request or a stream was waiting."""

    def __init__(self, message: str):
        super().__init__("connection_lost", message)


class NoDaemon(InstrumentError, ConnectionRefusedError):
    """No ftafm daemon answers at the URL (nothing listens there, or it is not a daemon's
    WebSocket). A :class:`ConnectionRefusedError` too, for code written against the bare
    one."""

    def __init__(self, url: str, reason: str):
        super().__init__(
            "no_daemon",
            f"no ftafm daemon answers at {url} ({reason}). Start one with `ftafm serve` "
            "(or `cargo run --release` in the repository; `--bind ADDR` for another "
            "address), or give the URL of a running one (url=..., or $FTAFM_URL).",
        )
        self.url = url
