"""Real third-party clients drive the emulator over loopback UDP (port 0, deadlines, no sleeps).

* pymavlink (ArduPilot personality): GUIDED, arm, takeoff, SET_POSITION_TARGET_LOCAL_NED;
  LOCAL_POSITION_NED moves to the target, never faster than the speed limit.
* MAVSDK 4.x (PX4 personality): connect, telemetry position, arm, offboard start,
  set_position_ned; the vehicle arrives.
"""

from __future__ import annotations

import asyncio
import math
import socket
import time

import numpy as np
import pytest

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from vehicle_emu.swarm import Swarm
from vehicle_emu.udp import run_in_thread

pytestmark = pytest.mark.udp

SPEEDUP = 10.0


class _Client:
    """Minimal pymavlink GCS over a plain UDP socket (no mavutil)."""

    def __init__(self, addr):
        self.addr = addr
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.mav = mavlink.MAVLink(None, 255, 190)
        self.mav.robust_parsing = True
        self.rx = mavlink.MAVLink(None, 255, 190)
        self.rx.robust_parsing = True
        self.last_hb = -1.0

    def send(self, msg):
        self.sock.sendto(msg.pack(self.mav), self.addr)
        self.mav.seq = (self.mav.seq + 1) % 256

    def heartbeat(self, force=False):
        # 1 Hz GCS heartbeat in *vehicle* time (wall period / speed-up), docs/design/mavlink.md §4.2.
        now = time.monotonic()
        if force or now - self.last_hb > 0.5 / SPEEDUP:
            self.last_hb = now
            self.send(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))

    def recv(self, timeout_s):
        self.sock.settimeout(timeout_s)
        try:
            data, _ = self.sock.recvfrom(65535)
        except TimeoutError:
            return []
        return [m for m in (self.rx.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]

    def wait_for(self, pred, deadline_s, what):
        end = time.monotonic() + deadline_s
        while time.monotonic() < end:
            self.heartbeat()
            for m in self.recv(0.05):
                if pred(m):
                    return m
        raise AssertionError(f"timed out waiting for {what}")

    def command(self, cmd, *params, deadline_s=5.0):
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(1, 1, cmd, 0, *p))
        ack = self.wait_for(
            lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd,
            deadline_s,
            f"ACK of {cmd}",
        )
        return ack.result


def test_pymavlink_guided_takeoff_goto_ardupilot():
    swarm = Swarm(1, personality="ardupilot", rng=np.random.default_rng(1))
    with run_in_thread(swarm, speedup=SPEEDUP) as emu:
        c = _Client(emu.addresses[0])
        try:
            c.heartbeat(force=True)
            hb = c.wait_for(lambda m: m.get_type() == "HEARTBEAT", 5, "vehicle heartbeat")
            assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
            # ArduPilot streams only HEARTBEAT until asked: request 10 Hz LOCAL_POSITION_NED.
            assert c.command(511, 32, 100_000) == 0
            assert c.command(176, 1, 4) == 0  # GUIDED
            c.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == 4, 5, "GUIDED")
            assert c.command(400, 1) == 0  # arm
            assert c.command(22, 0, 0, 0, 0, 0, 0, 10.0) == 0  # takeoff to 10 m
            c.wait_for(
                lambda m: m.get_type() == "LOCAL_POSITION_NED" and m.z < -9.5,
                20,
                "takeoff altitude",
            )
            target = (40.0, 30.0, -10.0)
            c.send(
                mavlink.MAVLink_set_position_target_local_ned_message(
                    0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 3576, *target, 0, 0, 0, 0, 0, 0, 0, 0
                )
            )
            limit = swarm.cores[0].params["WPNAV_SPEED"] / 100.0
            speeds, dists = [], []

            def arrived(m):
                if m.get_type() != "LOCAL_POSITION_NED":
                    return False
                speeds.append(math.hypot(m.vx, m.vy))
                dists.append(math.dist((m.x, m.y, m.z), target))
                return dists[-1] < 0.5

            c.wait_for(arrived, 30, "arrival at the target")
            assert max(speeds) <= limit + 1e-3
            assert max(speeds) > 0.5 * limit  # it really flew, at speed
            assert dists[0] > 40  # and it started far away
            assert np.all(np.diff(dists[::5]) < 0.5)  # monotonic approach (coarsely)
        finally:
            c.sock.close()


def _mavsdk_usable() -> str | None:
    try:
        import mavsdk  # noqa: F401
        from mavsdk.asyncio import Mavsdk  # noqa: F401
    except Exception as exc:  # noqa: BLE001
        return f"mavsdk not importable: {exc!r}"
    return None


@pytest.mark.skipif(_mavsdk_usable() is not None, reason=str(_mavsdk_usable()))
def test_mavsdk_offboard_px4():
    from mavsdk.asyncio import Configuration, ComponentType, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    swarm = Swarm(1, personality="px4", rng=np.random.default_rng(2))
    with run_in_thread(swarm, speedup=SPEEDUP) as emu:
        host, port = emu.addresses[0]

        async def scenario():
            cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
            async with Mavsdk(cfg) as sdk:
                await sdk.add_any_connection(f"udpout://{host}:{port}")
                system = await sdk.first_autopilot(timeout_s=10.0)
                assert system is not None, "MAVSDK did not discover the emulated PX4"
                telemetry = TelemetryAsync(system)
                action = ActionAsync(system)
                offboard = OffboardAsync(system)
                async for pos in telemetry.subscribe_position():
                    assert abs(pos.latitude_deg - swarm.home_lla[0]) < 1e-3
                    break
                await action.arm()
                await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -5.0, 0.0))
                # One recent setpoint is all PX4 asks (commander offboardCheck.cpp
                # OffboardChecks::checkAndReport: age < COM_OF_LOSS_T). set_position_ned above
                # has sent it, so the first start() must succeed (no retry).
                await offboard.start()
                await offboard.set_position_ned(PositionNedYaw(20.0, -10.0, -5.0, 0.0))
                async for pv in telemetry.subscribe_position_velocity_ned():
                    p = pv.position
                    if math.dist((p.north_m, p.east_m, p.down_m), (20, -10, -5)) < 0.7:
                        break
                await offboard.stop()

        asyncio.run(asyncio.wait_for(scenario(), 60))
