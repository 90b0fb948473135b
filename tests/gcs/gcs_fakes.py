"""Test helpers: a tiny in-test fake autopilot: pymavlink-encoded bytes out, decoded messages in.

Deliberately not ``vehicle_emu`` (gcs tests must stand alone; pair tests come later).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs.link import StationLink


class _Null:
    def write(self, _data) -> None:
        pass


class FakeAutopilot:
    """Encodes what a vehicle would send; decodes what the station sent it."""

    def __init__(
        self,
        sysid: int = 1,
        autopilot: int = mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
        compid: int = 1,
        vehicle_type: int = mav.MAV_TYPE_QUADROTOR,
        signing_key: bytes | None = None,
    ) -> None:
        self.sysid, self.autopilot, self.vehicle_type = sysid, autopilot, vehicle_type
        self.mav = mav.MAVLink(_Null(), sysid, compid)
        self.parser = mav.MAVLink(_Null(), 0, 0)
        self.parser.robust_parsing = True
        if signing_key is not None:
            self.parser.signing.secret_key = signing_key

    def sign_outgoing(self, key: bytes, unix_time_s: float, link_id: int = 0) -> None:
        """Sign every frame from now on (MAVLink 2 signing, timestamp from ``unix_time_s``)."""
        self.mav.signing.secret_key = key
        self.mav.signing.sign_outgoing = True
        self.mav.signing.link_id = link_id
        self.mav.signing.timestamp = int((unix_time_s - 1420070400) * 1e5)

    def _pack(self, msg) -> bytes:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(data)

    def pack(self, msg) -> bytes:
        """Any pymavlink message, as this vehicle would send it."""
        return self._pack(msg)

    def attitude(self, t_ms: int = 0) -> bytes:
        return self._pack(mav.MAVLink_attitude_message(t_ms, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))

    def local_position(self, t_ms: int = 0) -> bytes:
        return self._pack(mav.MAVLink_local_position_ned_message(t_ms, 1.0, 2.0, -3.0, 0, 0, 0))

    def heartbeat(self, custom_mode: int = 0, armed: bool = False) -> bytes:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
            mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
        )
        return self._pack(
            mav.MAVLink_heartbeat_message(
                self.vehicle_type, self.autopilot, base, custom_mode, mav.MAV_STATE_ACTIVE, 3
            )
        )

    def global_position(
        self,
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
        rel_alt_m: float,
        vel_ned_m_s=(0.0, 0.0, 0.0),
        hdg_cdeg: int = 0,
        time_boot_ms: int = 1000,
    ) -> bytes:
        return self._pack(
            mav.MAVLink_global_position_int_message(
                time_boot_ms,
                round(lat_deg * 1e7),
                round(lon_deg * 1e7),
                round(alt_amsl_m * 1000),
                round(rel_alt_m * 1000),
                *(round(v * 100) for v in vel_ned_m_s),
                hdg_cdeg,
            )
        )

    def home_position(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> bytes:
        return self._pack(
            mav.MAVLink_home_position_message(
                round(lat_deg * 1e7),
                round(lon_deg * 1e7),
                round(alt_amsl_m * 1000),
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                0.0,
                0.0,
                0,
            )
        )

    def ack(
        self,
        command: int,
        result: int = mav.MAV_RESULT_ACCEPTED,
        progress: int = 0,
        target_system: int = 255,
    ) -> bytes:
        return self._pack(
            mav.MAVLink_command_ack_message(command, result, progress, 0, target_system, 190)
        )

    def param_value(
        self, name: str, value: float, param_type: int = mav.MAV_PARAM_TYPE_REAL32
    ) -> bytes:
        return self._pack(mav.MAVLink_param_value_message(name.encode(), value, param_type, 1, 0))

    def statustext(self, text: str, severity: int = mav.MAV_SEVERITY_INFO) -> bytes:
        return self._pack(mav.MAVLink_statustext_message(severity, text.encode(), 0, 0))

    def decode(self, data: bytes) -> list:
        return [m for m in (self.parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]


def drain(link: StationLink) -> list:
    out = []
    while (ev := link.next_event()) is not None:
        out.append(ev)
    return out


def sent(link: StationLink, now_s: float, kind: str | None = None, addr=None) -> list:
    """Decode everything the link queued: [(msg, addr)] (filtered by type / address)."""
    parser = mav.MAVLink(_Null(), 0, 0)
    parser.robust_parsing = True
    out = []
    for data, to in link.datagrams_to_send(now_s):
        for m in parser.parse_buffer(data) or []:
            if (kind is None or m.get_type() == kind) and (addr is None or to == addr):
                out.append((m, to))
    return out
