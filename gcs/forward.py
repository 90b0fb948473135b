"""MAVLink forwarding to other ground stations, as MAVProxy's ``--out``.

Every frame a vehicle sends on any of the station's links goes out, unchanged, to every output
(QGroundControl, MAVProxy, a logger); what those send back is relayed to the link of the vehicle
it is addressed to (``target_system``; a broadcast target 0, a message without a target, or a
system never heard, goes to every link). With ``readonly`` nothing they send reaches a vehicle.

Outputs (connection strings as :mod:`gcs.connection`):

* ``udpout:HOST:PORT`` - send to HOST:PORT (QGC listens on 14550); replies come back to our socket.
* ``udpin:HOST:PORT`` - listen; send to every peer that has sent us something.
* ``tcpin:HOST:PORT`` - listen for TCP clients; send to all of them.

System ids. The station is sysid 255 (``StationConfig.sysid``), the one ArduPilot's GCS failsafe
counts (SYSID_MYGCS / MAV_GCS_SYSID), and QGroundControl's default is 255 too. Frames whose
source is the station's sysid are never forwarded (our heartbeats, or another 255 GCS on a
vehicle link, must not look like a vehicle to the outputs); and frames *from* an output with the
station's sysid are dropped (a warning once): they would feed the vehicles' GCS failsafe for us,
and their COMMAND_ACKs (addressed to 255) would be taken by the station as answers to its own
commands. Set QGC's "MAVLink system ID" (Application Settings -> MAVLink) to another value,
e.g. 254, for it to command vehicles through the forwarder.

Overrides. A message from an output that changes who flies a vehicle (:func:`override_of`: a
mode change, return / land / take-off, arm or disarm, a reposition or position target, a guided
"go to" mission item) is shown to ``on_override`` before it is routed. ``on_override`` (the
station's policy, ``phireman fly --forward-overrides``: :meth:`gcs.operations.Operator.
forwarded_override`) returns None to pass it on, or the reason it is refused: then the message is
not routed, and the client gets a COMMAND_ACK ``MAV_RESULT_DENIED`` (for a command) and a
STATUSTEXT (severity WARNING) with the reason, both sent as from the addressed vehicle (its sysid
and component): QGroundControl drops every message whose sysid is not the vehicle's
(``Vehicle::_mavlinkMessageReceived``, src/Vehicle/Vehicle.cc) and matches an ACK to its
pending command by the sending component and the command id. Everything else (heartbeats,
parameter and mission reads, stream requests) is routed as before.

Sans-clock: the forwarder keeps no timers; it needs the links' raw taps
(:meth:`gcs.aio.StationAdapter.add_tap` / :meth:`~gcs.aio.StationAdapter.send_raw`), and runs
on the station's event loop.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from dataclasses import dataclass
from typing import Any, Protocol
from collections.abc import Callable, Sequence

from gcs.autopilot import mode_name
from gcs.connection import ConnectionSpec, parse_connection
from gcs.wire import mavlink

__all__ = [
    "Forwarder",
    "split_frames",
    "OUTPUT_KINDS",
    "Override",
    "override_of",
    "OVERRIDE_COMMANDS",
    "OVERRIDE_POLICIES",
    "client_name",
]

log = logging.getLogger(__name__)

OUTPUT_KINDS = ("udpout", "udpin", "tcpin")

_V1, _V2 = 0xFE, 0xFD
_MAX_TCP_CLIENTS = 16
_MAX_UDP_PEERS = 16


#: What the station does with an override from a forwarded client (``phireman fly
#: --forward-overrides``): ``honour`` (the vehicle leaves the plan, as held by the operator) or
#: ``refuse`` (not passed on while the plan flies the vehicle; the client is told why).
OVERRIDE_POLICIES = ("honour", "refuse")

_C = mavlink
#: Commands (COMMAND_LONG / COMMAND_INT) that change who flies a vehicle. What QGroundControl
#: sends (mavlink/qgroundcontrol): its mode menu and its RTL / Land / Pause actions go through
#: ``Vehicle::setFlightMode`` (src/Vehicle/Vehicle.cc), which sends MAV_CMD_DO_SET_MODE when the
#: firmware plugin's ``MAV_CMD_DO_SET_MODE_is_supported()`` is true (ArduPilot,
#: src/FirmwarePlugin/APM/APMFirmwarePlugin.h) and the SET_MODE message otherwise (PX4: the base
#: ``FirmwarePlugin`` default); "Go to location" is MAV_CMD_DO_REPOSITION
#: (``APMFirmwarePlugin::guidedModeGotoLocation``, falling back to a guided MISSION_ITEM with
#: ``current`` 2; ``PX4FirmwarePlugin::pauseVehicle`` and ``guidedModeGotoLocation``); arm and
#: disarm are MAV_CMD_COMPONENT_ARM_DISARM (``Vehicle::setArmed``); take-off NAV_TAKEOFF. The
#: rest are the same actions as other ground stations and scripts send them (MAVProxy's ``rtl``,
#: ``land``, ``mode``, DroneKit's ``simple_goto``).
OVERRIDE_COMMANDS = frozenset(
    {
        _C.MAV_CMD_DO_SET_MODE,
        _C.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        _C.MAV_CMD_NAV_LAND,
        _C.MAV_CMD_NAV_TAKEOFF,
        _C.MAV_CMD_NAV_LOITER_UNLIM,
        _C.MAV_CMD_COMPONENT_ARM_DISARM,
        _C.MAV_CMD_DO_REPOSITION,
        _C.MAV_CMD_DO_PAUSE_CONTINUE,
        _C.MAV_CMD_DO_CHANGE_ALTITUDE,
        _C.MAV_CMD_DO_ORBIT,
        _C.MAV_CMD_MISSION_START,
        _C.MAV_CMD_DO_FLIGHTTERMINATION,
    }
)
#: Messages that steer a vehicle without a command (a client flying it in GUIDED / OFFBOARD).
_OVERRIDE_MESSAGES = frozenset(
    {
        "SET_MODE",
        "SET_POSITION_TARGET_GLOBAL_INT",
        "SET_POSITION_TARGET_LOCAL_NED",
        "SET_ATTITUDE_TARGET",
    }
)
_STATUSTEXT_LEN = 50  # MAVLink STATUSTEXT.text; longer texts go in chunks (id, chunk_seq)


def _cmd_name(command: int) -> str:
    e = mavlink.enums.get("MAV_CMD", {}).get(command)
    return e.name.replace("MAV_CMD_", "") if e is not None else f"command {command}"


@dataclass(frozen=True)
class Override:
    """A forwarded client's message that changes who flies the vehicles it addresses."""

    client: str
    """Who sent it, for people (:func:`client_name`: its address and MAVLink sysid)."""
    target_system: int
    target_component: int
    vids: tuple[tuple[int, int], ...]
    """The vehicles ``(link_id, sysid)`` it goes to (every vehicle heard for a broadcast; empty
    for a system never heard)."""
    message: str
    """The message type (``SET_MODE``, ``COMMAND_LONG``, ...)."""
    command: int | None = None
    """MAV_CMD of a COMMAND_LONG / COMMAND_INT (a refusal is acknowledged), else None."""
    custom_mode: int | None = None
    """The mode asked (SET_MODE, MAV_CMD_DO_SET_MODE), else None."""
    arm: bool | None = None
    """MAV_CMD_COMPONENT_ARM_DISARM: True to arm, False to disarm."""
    client_sysid: int = 0
    client_compid: int = 0

    def what(self, autopilot: int | None = None) -> str:
        """For people: ``SET_MODE RTL``, ``DO_SET_MODE LAND``, ``COMPONENT_ARM_DISARM disarm``
        (mode names from the vehicle's ``autopilot``, a HEARTBEAT value; numbers without it)."""
        name = self.message if self.command is None else _cmd_name(self.command)
        if self.custom_mode is not None:
            mode = (
                mode_name(autopilot, self.custom_mode)
                if autopilot is not None
                else f"custom_mode {self.custom_mode}"
            )
            return f"{name} {mode}"
        if self.arm is not None:
            return f"{name} {'arm' if self.arm else 'disarm'}"
        return name


def override_of(msg: Any) -> tuple[str, int | None, int | None, bool | None] | None:
    """``(message, command, custom_mode, arm)`` if the decoded message ``msg`` changes who flies
    a vehicle (see :data:`OVERRIDE_COMMANDS`), else None (read-only or harmless traffic)."""
    kind = msg.get_type()
    if kind in ("COMMAND_LONG", "COMMAND_INT"):
        cmd = int(msg.command)
        if cmd not in OVERRIDE_COMMANDS:
            return None
        if cmd == _C.MAV_CMD_DO_SET_MODE:
            return kind, cmd, int(msg.param2), None
        if cmd == _C.MAV_CMD_COMPONENT_ARM_DISARM:
            return kind, cmd, None, bool(msg.param1 >= 0.5)
        return kind, cmd, None, None
    if kind == "SET_MODE":
        return kind, None, int(msg.custom_mode), None
    if kind in _OVERRIDE_MESSAGES:
        return kind, None, None, None
    if kind in ("MISSION_ITEM", "MISSION_ITEM_INT") and int(msg.current) in (2, 3):
        # ArduPilot's guided "go to" (current 2) and altitude change (3): not a mission upload
        # (GCS_MAVLINK::handle_mission_item in libraries/GCS_MAVLink/GCS_Common.cpp).
        return kind, None, None, None
    return None


def client_name(source: object, sysid: int) -> str:
    """A forwarded client for people: ``127.0.0.1:51234 sysid 254`` (``source`` as the outputs
    give it: ``(connection text, peer address)``)."""
    peer = source[1] if isinstance(source, tuple) and len(source) == 2 else source
    if isinstance(peer, tuple) and len(peer) >= 2:
        peer = f"{peer[0]}:{peer[1]}"
    return f"{peer} sysid {sysid}"


class RawLink(Protocol):
    """What the forwarder needs of a station link (:class:`gcs.aio.StationAdapter`)."""

    link_id: int

    def add_tap(self, tap: Callable[[bytes, object], None]) -> None: ...

    def send_raw(self, frame: bytes) -> None: ...


def split_frames(buf: bytes | bytearray) -> tuple[list[bytes], int]:
    """Whole MAVLink v1/v2 frames at the start of ``buf`` (by header length; no CRC check: the
    receiving GCS checks). Returns ``(frames, consumed)``; bytes before a start marker are
    skipped, an incomplete frame at the end is left (``consumed`` stops before it)."""
    out, i, n = [], 0, len(buf)
    while i < n:
        b = buf[i]
        if b not in (_V1, _V2):
            i += 1
            continue
        if i + 2 > n:
            break
        ln = buf[i + 1]
        if b == _V1:
            total = ln + 8
        else:
            if i + 3 > n:
                break
            total = ln + 12 + (13 if buf[i + 2] & 0x01 else 0)
        if i + total > n:
            break
        out.append(bytes(buf[i : i + total]))
        i += total
    return out, i


def _src_sysid(frame: bytes) -> int:
    return frame[3] if frame[0] == _V1 else frame[5]


class Forwarder:
    """Forward vehicle traffic to ``outputs`` and route their messages back (module docstring).

    Parameters
    ----------
    outputs : connection strings (``udpout:``, ``udpin:``, ``tcpin:``)
    readonly : drop everything the outputs send
    gcs_sysid : the station's own MAVLink system id (never forwarded; dropped from outputs)
    on_override : called with every :class:`Override` before it is routed; returns None to pass
        it on, or why it is refused (module docstring). None: every override passes.
    """

    def __init__(
        self,
        outputs: Sequence[str],
        *,
        readonly: bool = False,
        gcs_sysid: int = 255,
        on_override: Callable[[Override], str | None] | None = None,
    ) -> None:
        self.specs: list[ConnectionSpec] = []
        for text in outputs:
            spec = parse_connection(text)
            if spec.kind not in OUTPUT_KINDS:
                raise ValueError(
                    f"forwarding output {text!r}: use udpout:H:P, udpin:H:P or "
                    f"tcpin:H:P (got a {spec.kind} connection)"
                )
            self.specs.append(spec)
        self.readonly = bool(readonly)
        self.gcs_sysid = int(gcs_sysid)
        self.on_override = on_override
        self._statustext_ids = itertools.cycle(range(1, 1 << 16))
        self.links: list[RawLink] = []
        self._links_of_sysid: dict[int, set[int]] = {}
        self._stream_bufs: dict[tuple[int, object], bytearray] = {}
        self._parsers: dict[object, Any] = {}  # pymavlink MAVLink parsers
        self._outputs: list[_Output] = []
        self.addresses: list[tuple[str, int]] = []
        """Local address of each output (udpin/tcpin: the bound port; udpout: our socket)."""
        self.stats = {
            "frames_out": 0,
            "frames_in": 0,
            "routed": 0,
            "dropped_readonly": 0,
            "dropped_own_sysid": 0,
            "dropped_undecodable": 0,
            "overrides_passed": 0,
            "overrides_refused": 0,
        }
        self._warned_sysid = False

    # ------------------------------------------------------------------ set-up

    def attach(self, link: RawLink, *, datagram: bool = True) -> None:
        """Tap one station link (``datagram``: UDP, each chunk holds whole frames)."""
        self.links.append(link)
        lid = link.link_id
        link.add_tap(lambda data, addr: self.from_vehicle(lid, data, addr, datagram=datagram))

    async def start(self) -> Forwarder:
        loop = asyncio.get_running_loop()
        for spec in self.specs:
            out = _Output(self, spec)
            await out.start(loop)
            self._outputs.append(out)
            assert out.local_address is not None  # set by start()
            self.addresses.append(out.local_address)
        return self

    def close(self) -> None:
        for out in self._outputs:
            out.close()
        self._outputs.clear()

    # ------------------------------------------------------------------ vehicles -> outputs

    def from_vehicle(self, link_id: int, data: bytes, addr: Any, *, datagram: bool = True) -> None:
        """Bytes heard on link ``link_id``: forward every frame not from the station's sysid."""
        if datagram:
            frames, _ = split_frames(data)
        else:  # a byte stream: keep the tail of a frame cut by the read
            key = (link_id, addr)
            buf = self._stream_bufs.setdefault(key, bytearray())
            buf += data
            frames, used = split_frames(buf)
            del buf[:used]
            if len(buf) > 4096:  # garbage without a frame start: do not grow forever
                buf.clear()
        keep = []
        for f in frames:
            sysid = _src_sysid(f)
            if sysid == self.gcs_sysid:
                continue
            self._links_of_sysid.setdefault(sysid, set()).add(link_id)
            keep.append(f)
        if not keep or not self._outputs:
            return
        payload = b"".join(keep)
        self.stats["frames_out"] += len(keep)
        for out in self._outputs:
            out.send(payload)

    # ------------------------------------------------------------------ outputs -> vehicles

    def from_output(self, data: bytes, source: object) -> None:
        """Bytes from an output peer ``source``: decode, filter, route by ``target_system``."""
        parser = self._parsers.get(source)
        if parser is None:
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            self._parsers[source] = parser
        try:
            msgs = parser.parse_buffer(bytes(data)) or []
        except Exception:  # noqa: BLE001 - garbage from a peer never takes the station down
            self.stats["dropped_undecodable"] += 1
            return
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.stats["dropped_undecodable"] += 1
                continue
            self.stats["frames_in"] += 1
            if self.readonly:
                self.stats["dropped_readonly"] += 1
                continue
            if msg.get_srcSystem() == self.gcs_sysid:
                self.stats["dropped_own_sysid"] += 1
                if not self._warned_sysid:
                    self._warned_sysid = True
                    log.warning(
                        "forwarding: a ground station on %s uses sysid %d, the station's "
                        "own: its messages are dropped. Give it another MAVLink system "
                        "ID (QGroundControl: Application Settings -> MAVLink, e.g. 254)",
                        source,
                        self.gcs_sysid,
                    )
                continue
            frame = bytes(msg.get_msgbuf())
            target = int(getattr(msg, "target_system", 0) or 0)
            ids = self._links_of_sysid.get(target) if target else None
            if self.on_override is not None and (kind := override_of(msg)) is not None:
                ov = Override(
                    client=client_name(source, msg.get_srcSystem()),
                    target_system=target,
                    target_component=int(getattr(msg, "target_component", 0) or 0),
                    vids=self._vids_of(target),
                    message=kind[0],
                    command=kind[1],
                    custom_mode=kind[2],
                    arm=kind[3],
                    client_sysid=msg.get_srcSystem(),
                    client_compid=msg.get_srcComponent(),
                )
                why = self.on_override(ov)
                if why is not None:
                    self.stats["overrides_refused"] += 1
                    self._refuse(ov, why, source)
                    continue
                self.stats["overrides_passed"] += 1
            for link in self.links:
                if ids is None or link.link_id in ids:
                    link.send_raw(frame)
                    self.stats["routed"] += 1

    def _vids_of(self, target: int) -> tuple[tuple[int, int], ...]:
        """The vehicles a message for ``target`` goes to (0: every vehicle heard)."""
        if target:
            return tuple((lid, target) for lid in sorted(self._links_of_sysid.get(target, ())))
        return tuple(sorted((lid, s) for s, lids in self._links_of_sysid.items() for lid in lids))

    def refusal_frames(self, ov: Override, reason: str) -> list[bytes]:
        """What a refused client is sent, as from each addressed vehicle: a COMMAND_ACK
        ``MAV_RESULT_DENIED`` for a command, then the ``reason`` as a STATUSTEXT (severity
        WARNING, in 50-character chunks of one ``id`` beyond 50 characters: MAVLink 2's
        STATUSTEXT ``id`` / ``chunk_seq``, which QGroundControl joins again)."""
        out: list[bytes] = []
        sysids = sorted({s for _, s in ov.vids}) or ([ov.target_system] if ov.target_system else [])
        text = reason.encode("utf-8")[:1000]
        chunks = [text[i : i + _STATUSTEXT_LEN] for i in range(0, len(text), _STATUSTEXT_LEN)]
        if len(chunks) > 1 and len(chunks[-1]) == _STATUSTEXT_LEN:
            chunks.append(b"")  # a full last chunk would leave the receiver waiting for more
        for sysid in sysids:
            mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=ov.target_component or 1)
            if ov.command is not None:
                ack = mavlink.MAVLink_command_ack_message(
                    ov.command,
                    mavlink.MAV_RESULT_DENIED,
                    0,
                    0,
                    ov.client_sysid,
                    ov.client_compid,
                )
                out.append(bytes(ack.pack(mav)))
            tid = next(self._statustext_ids) if len(chunks) > 1 else 0
            for k, chunk in enumerate(chunks):
                st = mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING, chunk, tid, k)
                out.append(bytes(st.pack(mav)))
        return out

    def _refuse(self, ov: Override, reason: str, source: object) -> None:
        """Answer a refused override to the client that sent it (and to no other)."""
        # Info only: the station's policy records and logs the refusal (once per retry burst).
        log.info("forwarding: %s from %s refused: %s", ov.what(), ov.client, reason)
        payload = b"".join(self.refusal_frames(ov, reason))
        for out in self._outputs:
            out.reply(payload, source)


class _Output:
    """One forwarding output's sockets."""

    def __init__(self, owner: Forwarder, spec: ConnectionSpec) -> None:
        self.owner = owner
        self.spec = spec
        self.local_address: tuple[str, int] | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._peers: dict[Any, None] = {}
        self._writers: list[asyncio.StreamWriter] = []
        self._server: asyncio.Server | None = None
        self._tasks: list[asyncio.Task[Any]] = []

    async def start(self, loop: asyncio.AbstractEventLoop) -> None:
        spec = self.spec
        if spec.kind in ("udpout", "udpin"):
            out = self

            class _P(asyncio.DatagramProtocol):
                def datagram_received(self, data: bytes, addr: Any) -> None:
                    if spec.kind == "udpin":
                        if addr not in out._peers and len(out._peers) >= _MAX_UDP_PEERS:
                            out._peers.pop(next(iter(out._peers)))
                        out._peers[addr] = None
                    out.owner.from_output(data, (spec.text, addr))

                def error_received(
                    self, exc: Exception
                ) -> None:  # nobody listening yet (ICMP): keep sending
                    log.debug("forward %s: %s", spec.text, exc)

            kw: dict[str, Any] = (
                {"remote_addr": spec.address}
                if spec.kind == "udpout"
                else {"local_addr": spec.address}
            )
            self._udp, _ = await loop.create_datagram_endpoint(_P, **kw)
            self.local_address = self._udp.get_extra_info("sockname")[:2]
        else:

            async def on_client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
                if len(self._writers) >= _MAX_TCP_CLIENTS:
                    writer.close()
                    return
                peer = writer.get_extra_info("peername")
                self._writers.append(writer)
                try:
                    while data := await reader.read(65536):
                        self.owner.from_output(data, (spec.text, peer))
                except (ConnectionError, OSError):
                    pass
                finally:
                    if writer in self._writers:
                        self._writers.remove(writer)
                    self.owner._parsers.pop((spec.text, peer), None)
                    writer.close()

            self._server = await asyncio.start_server(on_client, *spec.address)
            self.local_address = self._server.sockets[0].getsockname()[:2]

    def send(self, payload: bytes) -> None:
        self._write(payload, None)

    def reply(self, payload: bytes, source: object) -> None:
        """Send ``payload`` to the one peer ``source`` (``(connection text, address)`` as
        :meth:`Forwarder.from_output` is given it), if it is one of this output's."""
        if not (isinstance(source, tuple) and len(source) == 2 and source[0] == self.spec.text):
            return
        self._write(payload, source[1])

    def _write(self, payload: bytes, peer: Any) -> None:
        """``payload`` to every peer (``peer`` None) or to ``peer`` alone (udpout: its one
        destination either way)."""
        try:
            if self.spec.kind == "udpout":
                assert self._udp is not None  # started
                self._udp.sendto(payload)
            elif self.spec.kind == "udpin":
                assert self._udp is not None  # started
                for p in self._peers if peer is None else (peer,):
                    self._udp.sendto(payload, p)
            elif peer is None:
                for w in list(self._writers):
                    # A stalled client must not grow our memory: drop what it cannot take.
                    if w.transport.get_write_buffer_size() < (1 << 20):
                        w.write(payload)
            else:
                for w in list(self._writers):
                    if w.get_extra_info("peername") == peer:
                        w.write(payload)
        except OSError as exc:
            log.debug("forward %s: %s", self.spec.text, exc)

    def close(self) -> None:
        if self._udp is not None:
            self._udp.close()
        if self._server is not None:
            self._server.close()
        for w in self._writers:
            w.close()
        self._writers.clear()
