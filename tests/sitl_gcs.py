"""A scripted ground station for the real-firmware tests that talk to one SITL with pymavlink
directly (tests/integration/test_sitl_rally.py, test_sitl_terrain.py): the GCS heartbeat, the
receive loop, and the vehicle's position and state from its messages."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from gcs.wire import mavlink

__all__ = ["pump", "note_vehicle"]


def pump(
    conn: Any,
    seconds: float,
    on_message: Callable[[Any], None],
    until: Callable[[], bool] | None = None,
) -> bool:
    """Be the GCS for up to ``seconds`` wall seconds: a heartbeat every 0.5 s, every message
    received to ``on_message``. True as soon as ``until()`` holds (``until`` None: True at the
    end); False when the time ran out first."""
    end = time.monotonic() + seconds
    last_hb = 0.0
    while time.monotonic() < end:
        if time.monotonic() - last_hb > 0.5:
            conn.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4)
            last_hb = time.monotonic()
        m = conn.recv_match(blocking=True, timeout=0.2)
        if m is None:
            continue
        on_message(m)
        if until is not None and until():
            return True
    return until is None


def note_vehicle(state: dict, m: Any) -> None:
    """The autopilot's GLOBAL_POSITION_INT (``lat``, ``lon`` degrees, ``rel`` metres above home)
    and HEARTBEAT (``sysid``, ``armed``, ``mode``) into ``state``."""
    if m.get_srcComponent() != 1:
        return
    kind = m.get_type()
    if kind == "GLOBAL_POSITION_INT":
        state.update(lat=m.lat * 1e-7, lon=m.lon * 1e-7, rel=m.relative_alt * 1e-3)
    elif kind == "HEARTBEAT" and m.type != mavlink.MAV_TYPE_GCS:
        state.update(sysid=m.get_srcSystem(), armed=bool(m.base_mode & 128), mode=m.custom_mode)
