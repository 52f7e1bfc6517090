"""pytest fixtures for test suites that drive an ftafm daemon (registered by the package
as a pytest plugin; see :mod:`ftafm.testing`)."""

from __future__ import annotations

from typing import Iterator

import pytest

from .client import Instrument
from .testing import Daemon


@pytest.fixture(scope="session")
def ftafm_daemon() -> Iterator[Daemon]:
    """An ``ftafm serve`` on 127.0.0.1:0 and its default config, for the session."""
    with Daemon() as daemon:
        yield daemon


@pytest.fixture
def ftafm_instrument(ftafm_daemon: Daemon) -> Iterator[Instrument]:
    """A connected Instrument; the daemon's settings are restored after the test."""
    with Instrument(ftafm_daemon.url) as inst:
        saved = inst.settings_toml()
        try:
            yield inst
        finally:
            inst._run(inst._async.request("load_settings", toml=saved))
