"""Helpers for vehicle emulator tests: a tiny in-memory GCS speaking pymavlink."""

from __future__ import annotations


from pymavlink.dialects.v20 import ardupilotmega as mavlink

GCS_ADDR = ("10.0.0.1", 14550)


class FakeGcs:
    """Encodes GCS messages and decodes what a core or swarm sends (no sockets)."""

    def __init__(self, sysid: int = 255, signing_key: bytes | None = None):
        self.mav = mavlink.MAVLink(None, sysid, 190)
        self.rx = mavlink.MAVLink(None, sysid, 190)
        self.rx.robust_parsing = True
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = 1_000_000

    def frame(self, msg) -> bytes:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf

    def heartbeat(self) -> bytes:
        return self.frame(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))

    def command(self, cmd: int, *params, target: int = 1) -> bytes:
        p = list(params) + [0.0] * (7 - len(params))
        return self.frame(mavlink.MAVLink_command_long_message(target, 1, cmd, 0, *p))

    def local_target(self, x, y, z, mask=3576, frame=1, vx=0.0, vy=0.0, vz=0.0, target=1):
        return self.frame(
            mavlink.MAVLink_set_position_target_local_ned_message(
                0, target, 1, frame, mask, x, y, z, vx, vy, vz, 0, 0, 0, 0, 0
            )
        )

    def decode(self, datagrams) -> list:
        out = []
        for item in datagrams:
            data = item[0] if len(item) == 2 else item[1]
            out += [m for m in (self.rx.parse_buffer(data) or []) if m.get_type() != "BAD_DATA"]
        return out


def acks(msgs, command=None):
    return [
        m.result
        for m in msgs
        if m.get_type() == "COMMAND_ACK" and (command is None or m.command == command)
    ]


def of_type(msgs, mtype):
    return [m for m in msgs if m.get_type() == mtype]
