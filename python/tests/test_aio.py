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


def test_the_async_client_has_the_node_tree_and_set_transaction(ftafm_daemon: Daemon) -> None:
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url) as inst:
            saved = await inst.settings_toml()
            try:
                # The tree, as the sync client has it, its calls awaited.
                assert await inst.sample.youngs_modulus() == 129e9
                t = await inst.sample.youngs_modulus(116.1e9)
                assert t is not None and await inst.get("/sample/youngs_modulus") == 116.1e9
                assert (await inst.sample(16))["harmonic"] == 17, "sample() is the output"
                assert len(inst.demods) == 32 and await inst.demods[16].harmonic() == 17
                under = await inst.demods[16]()
                assert under["/demods/16/harmonic"] == 17 and "/demods/16/enable" in under
                assert inst.drive.frequency.node.unit == "Hz"
                with pytest.raises(AttributeError, match="youngs_modulus"):
                    inst.sample.youngs_modulos
                # One change at the end of the block, nothing before it.
                async with inst.set_transaction() as tr:
                    assert await inst.surface.distance(15e-9) is None
                    await inst.set("/demods/3/harmonic", 6)
                    assert await inst.get("/surface/distance") == 20e-9
                assert tr.t is not None
                assert tr.values == {"/surface/distance": 15e-9, "/demods/3/harmonic": 6}
                assert await inst.get_many(["/surface/distance", "/demods/3/harmonic"]) == {
                    "/surface/distance": 15e-9,
                    "/demods/3/harmonic": 6,
                }
                # A refused batch changes nothing; a block that raises sends nothing.
                with pytest.raises(ftafm.InstrumentError, match="/demods/3/harmonic"):
                    async with inst.set_transaction():
                        await inst.surface.distance(12e-9)
                        await inst.demods[3].harmonic(-2)
                with pytest.raises(KeyError):
                    async with inst.set_transaction():
                        await inst.surface.distance(12e-9)
                        raise KeyError("a script's own error")
                assert await inst.get("/surface/distance") == 15e-9
                with pytest.raises(RuntimeError, match="already open"):
                    async with inst.set_transaction():
                        async with inst.set_transaction():
                            pass
            finally:
                await inst.request("load_settings", toml=saved)

    asyncio.run(main())

