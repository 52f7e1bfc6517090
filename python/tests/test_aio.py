"""The asyncio client."""

from __future__ import annotations

import asyncio

import pytest

import ftafm
import ftafm.aio
from ftafm.testing import Daemon


def test_the_async_client_does_what_the_sync_one_does(ftafm_daemon: Daemon) -> None:
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url) as inst:
            saved = await inst.settings_toml()
            try:
                t = await inst.set_many({"/surface/distance": 14e-9})
                assert t is not None
                await inst.wait_until(t + 0.02)
                sample = await inst.sample(0)
                assert sample["t"] >= t + 0.02
                # Two streams read at once on one connection, each whole.
                demods, status = await asyncio.gather(
                    inst.poll("demods", 0.6), inst.poll("status", 0.6)
                )
                assert len(demods) >= 500 and demods.gaps == 0
                assert len(status) >= 1
                with pytest.raises(ftafm.InstrumentError) as e:
                    await inst.set("/surface/distance", -1.0)
                assert e.value.code == "invalid_value"
            finally:
                await inst.request("load_settings", toml=saved)

    asyncio.run(main())


def test_a_sweep_point_may_take_longer_than_a_request(ftafm_daemon: Daemon) -> None:
    # Each point settles 4 s of simulated (here: wall-clock) time, beyond the client's 3 s
    # request timeout: the sweep waits up to SWEEP_POINT_TIMEOUT per point by default.
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url, timeout=3.0) as inst:
            saved = await inst.settings_toml()
            try:
                result = await inst.sweep(
                    "/surface/distance", 200e-9, 190e-9, 2, settling=4.0
                )
                assert result.outcome == "done" and len(result) == 2
            finally:
                await inst.request("load_settings", toml=saved)

    assert ftafm.aio.SWEEP_POINT_TIMEOUT > 4.0
    asyncio.run(main())
