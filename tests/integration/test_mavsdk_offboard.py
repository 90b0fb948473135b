"""MAVSDK's standard offboard sequence, without a retry loop, against the emulated PX4.

The sequence every MAVSDK example uses (examples/offboard_position_ned.py)::

    await drone.action.arm()
    await drone.offboard.set_position_ned(PositionNedYaw(0, 0, -5, 0))
    await drone.offboard.start()

``set_position_ned`` sends ONE setpoint and starts MAVSDK's 20 Hz resend; ``start()`` follows at
once. Real PX4 accepts it: the OFFBOARD mode requirement is only that the last
``offboard_control_mode`` is younger than COM_OF_LOSS_T (commander
HealthAndArmingChecks/checks/offboardCheck.cpp ``OffboardChecks::checkAndReport``), and
mavlink_receiver.cpp ``handle_message_set_position_target_local_ned`` publishes it on every
setpoint. An emulator that demands > 1 s of streaming first makes ``start()`` fail with
TEMPORARILY_REJECTED, which this test would catch.

Loopback UDP on ephemeral ports, deadlines instead of sleeps, marked ``udp``.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from vehicle_emu.swarm import Swarm
from vehicle_emu.udp import run_in_thread

from test_emulator_udp import _mavsdk_usable

pytestmark = pytest.mark.udp

SPEEDUP = 5.0
_WHY_NOT = _mavsdk_usable()


@pytest.mark.skipif(_WHY_NOT is not None, reason=f"MAVSDK cannot run here: {_WHY_NOT}")
def test_mavsdk_offboard_start_without_retry_px4():
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    swarm = Swarm(1, personality="px4", rng=np.random.default_rng(3))
    core = swarm.cores[0]

    async def scenario() -> tuple[float, str]:
        cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        try:
            sdk_cm = Mavsdk(cfg)
        except Exception as exc:  # noqa: BLE001 - the native library failed to load
            pytest.skip(f"MAVSDK cannot run here: {exc!r}")
        async with sdk_cm as sdk:
            host, port = emu.addresses[0]
            await sdk.add_any_connection(f"udpout://{host}:{port}")
            system = await sdk.first_autopilot(timeout_s=10.0)
            assert system is not None, "MAVSDK did not discover the emulated PX4"
            telemetry, action = TelemetryAsync(system), ActionAsync(system)
            offboard = OffboardAsync(system)
            async for health in telemetry.subscribe_health():
                if health.is_global_position_ok and health.is_home_position_ok:
                    break
            await action.arm()
            await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -5.0, 0.0))
            await offboard.start()  # no retry: must succeed the first time
            mode = emu.call(lambda: core.mode_name)
            async for pv in telemetry.subscribe_position_velocity_ned():
                if pv.position.down_m < -4.5:
                    break
            down_m = pv.position.down_m
            await offboard.stop()
            return down_m, mode

    with run_in_thread(swarm, speedup=SPEEDUP) as emu:
        down_m, mode = asyncio.run(asyncio.wait_for(scenario(), 60))
    assert mode == "OFFBOARD"
    assert down_m < -4.5 and math.isfinite(down_m)  # it climbed towards the 5 m setpoint
