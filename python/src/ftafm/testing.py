"""A daemon for test suites: ``ftafm.testing.Daemon`` starts ``ftafm serve`` on
127.0.0.1 port 0, reads the address it bound, and stops it (SIGTERM) on exit.

The package registers a pytest plugin with two fixtures:

- ``ftafm_daemon``: a daemon on its default config for the whole session (its ``url``);
- ``ftafm_instrument``: a connected :class:`ftafm.Instrument` to it, per test, whose
  settings are restored after the test.

The binary is ``$FTAFM_BIN`` if set, else ``ftafm`` on the PATH.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import threading
from typing import Iterator, Sequence

_ADDRESS = re.compile(r"WebSocket (ws://\S+/ws)")


class Daemon:
    """An ``ftafm serve`` process on 127.0.0.1 and a free port.

    ``args`` are extra flags (e.g. ``["--preset", "tap300"]`` or ``["--config", path]``);
    ``binary`` defaults to ``$FTAFM_BIN`` or ``ftafm`` on the PATH; ``startup`` bounds the
    wait for it to listen, in seconds.
    """

    def __init__(
        self,
        args: Sequence[str] = (),
        *,
        binary: str | None = None,
        startup: float = 60.0,
    ):
        exe = binary or os.environ.get("FTAFM_BIN") or shutil.which("ftafm")
        if not exe:
            raise FileNotFoundError(
                "no ftafm binary: set FTAFM_BIN or put ftafm on the PATH (cargo install --path .)"
            )
        self.process = subprocess.Popen(
            [exe, "serve", "--bind", "127.0.0.1:0", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.url = self._wait_for_address(startup)
        # Keep draining both pipes so the daemon never blocks on a full one.
        self.log: list[str] = []
        for pipe in (self.process.stdout, self.process.stderr):
            threading.Thread(target=self._drain, args=(pipe,), daemon=True).start()

    def _wait_for_address(self, startup: float) -> str:
        found: list[str] = []

        def read() -> None:
            assert self.process.stdout is not None
            for line in self.process.stdout:
                m = _ADDRESS.search(line)
                if m:
                    found.append(m.group(1))
                    return

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        reader.join(startup)
        if not found:
            self.process.kill()
            err = self.process.stderr.read() if self.process.stderr else ""
            raise RuntimeError(f"ftafm did not start within {startup} s: {err.strip()}")
        return found[0]

    def _drain(self, pipe: object) -> None:
        for line in pipe:  # type: ignore[attr-defined]
            if len(self.log) < 10_000:
                self.log.append(line)

    def stop(self, timeout: float = 30.0) -> int:
        """Stops the daemon (SIGTERM) and returns its exit code."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def __enter__(self) -> "Daemon":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def daemon_session() -> Iterator[Daemon]:
    """A daemon for a fixture's lifetime."""
    with Daemon() as d:
        yield d
