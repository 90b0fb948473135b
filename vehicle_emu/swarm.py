"""The multi-vehicle emulator: one world of N vehicles, N vehicle cores, a router and the radio.

Sans-I/O like the cores: bytes and ``now_s`` in, ``(endpoint, bytes, addr)`` out, timers.
:mod:`vehicle_emu.udp` binds it to sockets; tests drive it with an explicit clock.

Identity: vehicle ``index`` (array row, 0..N-1) is distinct from its MAVLink identity
``(network, sysid)``: ``network = index // 254``, ``sysid = index % 254 + 1``. Sysids are 8-bit
and 255 is the GCS, so more than 254 vehicles are split over several MAVLink networks
(docs/design/mavlink.md §5.4), each served by its own endpoint(s).

Endpoints (how a GCS reaches vehicles):

* ``mux=False`` (SITL style): one endpoint per vehicle; endpoint ``e`` is vehicle ``e``; the
  UDP adapter binds ``base_port + e``.
* ``mux=True``: one endpoint per network; frames are routed by their ``target_system`` (0 or
  no target field = every vehicle of that network).

Each endpoint sends to its *peers*: configured GCS addresses (``udpout`` style, permanent) plus
the addresses it has heard from. Learned peers are forgotten after ``peer_timeout_s`` without a
datagram from them, and at most ``max_peers`` are kept per endpoint (the least recently heard is
dropped for a new one). Real autopilots are stricter: PX4's mavlink UDP instance latches one
partner (mavlink_receiver.cpp "partner IP"), MAVProxy's ``udpin`` answers only its last sender;
several peers are kept here so that a station and a third-party GCS can share an endpoint, but a
stream of one-off senders (scanners, restarted clients on new ports) can no longer multiply the
telemetry without bound. The radio decides what gets through (:mod:`vehicle_emu.radio`).

One tick (:meth:`Swarm.handle_timer`): attrition -> autopilot rules of every core ->
vectorised physics step -> geodetic update -> radio update -> ground-truth record -> telemetry.

Longer than ~600 lines on purpose: the router, the peers, the tick and the ground truth all
work on the swarm's shared per-vehicle state; split, each part would reach into the others.

Length (a little over the ~600 lines this code base aims for): the swarm is the one place where
frames meet vehicles (routing by sysid, one decode per broadcast frame, batched telemetry, the
radio between vehicles); cut further, the router and the batch path would share private state
across files.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import cast

import numpy as np

from planner.geometry import tasks_connected
from planner.metrics import task_uptime, uptime_series

from . import events as ev
from . import wire
from .attrition import Attrition
from .battery import BatteryConfig, SwapConfig
from .link import TICK_S, RateLimitedLog, VehicleCore
from .physics import Physics
from .radio import Radio, RadioConfig
from .terrain import CRASH_DEPTH_M, TOUCHDOWN_SPEED_H_M_S, Ground
from .telemetry_batch import BatchTelemetry

#: The least height above the ground (``Swarm.least_agl_m``) counts a vehicle in GUIDED or
#: OFFBOARD once it has been this high, metres: the station's flight, not a take-off or landing.
CLEARANCE_FROM_AGL_M = 10.0

__all__ = [
    "Swarm",
    "TruthLog",
    "VEHICLES_PER_NETWORK",
    "identity_of_index",
    "PEER_TIMEOUT_S",
    "MAX_PEERS",
]

log = logging.getLogger(__name__)

VEHICLES_PER_NETWORK = 254
_MAX_EVENTS = 100_000
#: The ground crew a swarm with batteries has unless told otherwise (docs/design/endurance.md §6.4).
DEFAULT_SWAP = SwapConfig()
#: Default silence (vehicle seconds) after which a learned peer is forgotten: 6 x ArduPilot's
#: FS_GCS_TIMEOUT default (5 s), 3 x PX4's COM_DL_LOSS_T default (10 s); by then the vehicles
#: themselves have declared that GCS lost.
PEER_TIMEOUT_S = 30.0
#: Default cap on learned peers per endpoint.
MAX_PEERS = 8
_PEER_SWEEP_PERIOD_S = 1.0
#: Decoded inbound datagrams kept for the delayed deliveries of the same bytes to other cores (a
#: broadcast reaches each member after its own hop delay); cleared when full.
_DECODE_CACHE_SIZE = 256


def identity_of_index(index: int, per_network: int = VEHICLES_PER_NETWORK) -> tuple[int, int]:
    """Array row -> (network, sysid)."""
    return index // per_network, index % per_network + 1


def grid_spawn_ned_m(n: int, spacing_m: float) -> np.ndarray:
    """(N, 3) spawn positions on a square grid centred on the origin, on the ground."""
    side = max(1, math.ceil(math.sqrt(n)))
    k = np.arange(n)
    north = (k // side - (side - 1) / 2) * spacing_m
    east = (k % side - (side - 1) / 2) * spacing_m
    return np.column_stack([north, east, np.zeros(n)])


@dataclass
class TruthLog:
    """Ground truth sampled every ``period_s`` of vehicle time (row t = one sample)."""

    t_s: list
    pos_ned_m: list
    """Per sample: (N, 3) float64 world NED positions."""
    alive: list
    """Per sample: (N,) bool."""
    active: list
    """Per sample: (N,) bool — connected to the base (hears the GCS)."""
    task_connected: list
    """Per sample: (M,) bool — A_i(t), only if a ``task_pos_fn`` was given."""

    def arrays(self) -> dict[str, np.ndarray]:
        out = {
            "t_s": np.asarray(self.t_s),
            "pos_ned_m": np.asarray(self.pos_ned_m),
            "alive": np.asarray(self.alive),
            "active": np.asarray(self.active),
        }
        if self.task_connected:
            out["task_connected"] = np.asarray(self.task_connected)
        return out


class Swarm:
    """N emulated vehicles sharing one world.

    Parameters
    ----------
    n_vehicles : int
    personality : str or sequence of str
        'ardupilot' / 'px4', one for all or one per vehicle.
    home_lla : (lat_deg, lon_deg, alt_amsl_m)
        World origin = base station position (the radio node of the GCS).
    spawn_ned_m : (N, 3) array, optional
        Spawn (home / EKF origin) of each vehicle, world NED metres; default a ground grid with
        ``spawn_spacing_m`` spacing around the base.
    radio : RadioConfig
    hazard_per_s : float or (N,) array
        Attrition rate (per second of vehicle time).
    kills : iterable of (t_s, index)
        Scripted kills.
    task_pos_fn : callable t_s -> (M, 2) array, optional
        Task positions (north, east metres) for ground-truth TU1/TU2.
    mux : bool
        One endpoint per network instead of one per vehicle.
    gcs_addrs : iterable
        Addresses every endpoint sends to from the start (``udpout``).
    signing_key : bytes, optional
        32-byte key installed in every vehicle.
    trusted_addrs : iterable
        Source addresses allowed to send SETUP_SIGNING (see :class:`VehicleCore`).
    params : mapping, optional
        Parameter overrides for every vehicle; ``per_vehicle_params`` maps index -> overrides.
    stream_rates_hz : mapping msg_id -> Hz, optional
        Streams switched on at boot in every vehicle (as a GCS would request them).
    rng : numpy.random.Generator
        Root generator; radio and attrition get spawned children.
    now_s : float
        Vehicle clock at boot.
    tick_s : float
        Autopilot / physics / telemetry tick (vehicle seconds).
    truth_period_s : float
        Ground-truth sampling period (vehicle seconds); TU1/TU2 use these samples.
    radio_period_s : float
        How often connectivity is recomputed (vehicle seconds; also on every kill). At 10 m/s
        the default 0.1 s is 1 m of motion; 0 recomputes every tick.
    peer_timeout_s : float
        A learned peer (not one of ``gcs_addrs``) silent this long (vehicle seconds) is
        forgotten. Under a real-time speed-up S a GCS that does not scale its send rate is
        silent S times longer in vehicle time; raise this accordingly.
    max_peers : int
        Learned peers kept per endpoint (least recently heard dropped first).
    battery : BatteryConfig, optional
        Drain batteries (docs/design/endurance.md §6): the firmware's battery monitor, its
        telemetry and failsafes in every vehicle; a vehicle that runs its pack empty is lost.
        None (default): endless batteries, the emulator as it always was.
    battery_swap : SwapConfig or None
        With batteries: the ground crew at the base (on by default): a vehicle landed and
        disarmed at its home with a used pack powers off, and boots again with a full one
        ``swap_time_s`` later (parameters kept, ``time_boot_ms`` from 0). None: no swaps.
    telemetry : {'batch', 'reference'}
        'batch' (default): each message type packed once per tick for every vehicle due
        (:mod:`vehicle_emu.telemetry_batch`); 'reference': every vehicle builds and packs its
        own messages with pymavlink (the slower path the batch is tested against byte for byte).
    ground : Ground, optional
        The terrain (:mod:`vehicle_emu.terrain`, docs/terrain.md §5): links must clear it, the
        vehicles stand on it and one flown into it is lost, and every ArduPilot vehicle runs its
        terrain database (TERRAIN_REQUEST to the station, :mod:`vehicle_emu.core_terrain`) with
        ``terrain_spacing_m`` between posts (TERRAIN_SPACING). None: the flat earth.
    """

    def __init__(
        self,
        n_vehicles: int,
        *,
        personality="ardupilot",
        home_lla=(47.397742, 8.545594, 488.0),
        spawn_ned_m=None,
        spawn_spacing_m: float = 3.0,
        radio: RadioConfig | None = None,
        hazard_per_s=0.0,
        kills=(),
        airborne_only_attrition: bool = False,
        task_pos_fn=None,
        mux: bool = False,
        gcs_addrs=(),
        signing_key: bytes | None = None,
        trusted_addrs=(),
        params=None,
        per_vehicle_params=None,
        stream_rates_hz=None,
        rng: np.random.Generator | None = None,
        now_s: float = 0.0,
        tick_s: float = TICK_S,
        truth_period_s: float = 1.0,
        ekf_ready_after_s: float = 0.0,
        unix_time_at_zero_s: float = 1.7e9,
        max_speed_h_m_s: float = 10.0,
        tau_pos_s: float = 1.0,
        radio_period_s: float = 0.1,
        peer_timeout_s: float = PEER_TIMEOUT_S,
        max_peers: int = MAX_PEERS,
        telemetry: str = "batch",
        battery: BatteryConfig | None = None,
        battery_swap: SwapConfig | None = DEFAULT_SWAP,
        ground: Ground | None = None,
        terrain_spacing_m: int = 100,
    ) -> None:
        if n_vehicles < 1:
            raise ValueError(f"n_vehicles must be >= 1, got {n_vehicles}")
        n = int(n_vehicles)
        self.n = n
        personalities = [personality] * n if isinstance(personality, str) else list(personality)
        if len(personalities) != n:
            raise ValueError("personality sequence must have one entry per vehicle")
        rng = rng if rng is not None else np.random.default_rng(0)
        radio_rng, attrition_rng = rng.spawn(2)
        self.home_lla = cast(tuple[float, float, float], tuple(float(v) for v in home_lla))
        spawn = (
            grid_spawn_ned_m(n, spawn_spacing_m)
            if spawn_ned_m is None
            else np.asarray(spawn_ned_m, dtype=float).reshape(n, 3)
        )
        self.physics = Physics(
            spawn, origin_lla=self.home_lla, max_speed_h_m_s=max_speed_h_m_s, tau_pos_s=tau_pos_s
        )
        if battery is not None:
            self.physics.enable_battery(battery)
        self.battery_swap = battery_swap if battery is not None else None
        self.powered = np.ones(n, dtype=bool)
        """(N,) bool: the autopilot is on (False during a battery swap)."""
        self.boot_at_s = np.full(n, np.inf)
        """(N,) when each powered-off vehicle boots again, vehicle seconds."""
        #: The terrain (vehicle_emu.terrain): links over it, ground contact; None: flat earth.
        self.ground = ground
        #: While True (a mission's run), the least height above the ground of a flying vehicle
        #: at any tick is kept in ``least_agl_m`` (metres; None: none flew yet).
        self.track_clearance = False
        self.least_agl_m: float | None = None
        #: ... and the greatest (metres; None: none flew yet).
        self.highest_agl_m: float | None = None
        self._risen = np.zeros(n, dtype=bool)
        #: ... counting a vehicle once it has been this high (a mission sets its cruise height).
        self.clearance_from_agl_m = CLEARANCE_FROM_AGL_M
        if ground is not None:
            self.physics.ground_down_m = ground.ground_down_m(self.physics.pos_ned_m[:, :2])
        self.radio = Radio(radio or RadioConfig(), np.zeros(3), radio_rng, ground=ground)
        self.attrition = Attrition(
            n, hazard_per_s, kills, attrition_rng, airborne_only=airborne_only_attrition
        )
        self.task_pos_fn = task_pos_fn
        self.tick_s = float(tick_s)
        self.truth_period_s = float(truth_period_s)
        self.radio_period_s = float(radio_period_s)
        self._last_radio_s = -math.inf

        self.network_of_index = np.arange(n) // VEHICLES_PER_NETWORK
        self.sysid_of_index = np.arange(n) % VEHICLES_PER_NETWORK + 1
        self.n_networks = int(self.network_of_index[-1]) + 1
        self._index_of = {
            (int(self.network_of_index[i]), int(self.sysid_of_index[i])): i for i in range(n)
        }
        per_vehicle_params = per_vehicle_params or {}
        #: Rate limits for warnings caused by remote input (one shared by all cores).
        self.log_limiter = RateLimitedLog(log)
        core_limiter = RateLimitedLog(logging.getLogger(VehicleCore.__module__))
        self.cores: list[VehicleCore] = []
        self._personalities = personalities
        self._core_kw = dict(
            trusted_addrs=trusted_addrs,
            ekf_ready_after_s=ekf_ready_after_s,
            unix_time_at_zero_s=unix_time_at_zero_s,
            log_limiter=core_limiter,
        )
        self._stream_rates_hz = dict(stream_rates_hz or {})
        for i in range(n):
            p = dict(params or {})
            p.update(per_vehicle_params.get(i, {}))
            self.cores.append(self._make_core(i, now_s, p, signing_key))
        if ground is not None:  # ArduPilot's terrain database, filled by the station
            for core in self.cores:
                if core.personality == "ardupilot":
                    core.enable_terrain(terrain_spacing_m, now_s)
        #: Indices of the cores that queued frames since datagrams_to_send last looked (each
        #: core adds its own): the flush after every datagram received visits those, not all.
        self._out_dirty: set[int] = {i for i, core in enumerate(self.cores) if core._out}
        for core in self.cores:
            core._out_dirty = self._out_dirty

        self.mux = bool(mux)
        self.n_endpoints = self.n_networks if self.mux else n
        self._gcs_addrs = list(gcs_addrs)
        if not peer_timeout_s > 0 or int(max_peers) < 1:
            raise ValueError("peer_timeout_s must be > 0 and max_peers >= 1")
        self.peer_timeout_s = float(peer_timeout_s)
        self.max_peers = int(max_peers)
        self._static_peers: list[list] = [list(self._gcs_addrs) for _ in range(self.n_endpoints)]
        #: Per endpoint: learned addr -> last heard (vehicle s), least recently heard first.
        self._learned: list[dict] = [{} for _ in range(self.n_endpoints)]
        self._endpoints_learned: set[int] = set()
        self._next_peer_sweep_s = float(now_s) + _PEER_SWEEP_PERIOD_S
        #: Per endpoint: every destination (static then learned); rebuilt when peers change.
        self.peers: list[list] = [list(p) for p in self._static_peers]
        self._members = [
            np.flatnonzero(self.network_of_index == k).tolist() for k in range(self.n_networks)
        ]
        #: Decodes a broadcast frame once for every member without a signing key.
        self._broadcast_codec = wire.Codec(1)
        #: Datagram -> its decode by the broadcast codec, for delayed deliveries (_decode_shared).
        self._decoded: dict[bytes, wire.DecodeResult] = {}

        self._t_s = float(now_s)
        self._next_truth_s = float(now_s) + self.truth_period_s
        self._delayed: list = []
        self._delay_seq = 0
        self._events: deque = deque(maxlen=_MAX_EVENTS)
        self.truth = TruthLog([], [], [], [], [])
        self.stats = {
            "datagrams_in": 0,
            "datagrams_out": 0,
            "dropped_radio_in": 0,
            "dropped_radio_out": 0,
            "dropped_dead": 0,
            "unroutable": 0,
            "ticks": 0,
            "peers_learned": 0,
            "peers_expired": 0,
            "peers_evicted": 0,
            "terrain_crashes": 0,
        }
        self._radio_dirty = False
        if telemetry not in ("batch", "reference"):
            raise ValueError(f"telemetry must be 'batch' or 'reference', got {telemetry!r}")
        #: 'batch': each message type packed once per tick for all vehicles due
        #: (vehicle_emu.telemetry_batch); 'reference': every core builds its own (the slow path
        #: the batch output is tested against, byte for byte).
        self.telemetry = telemetry
        self._batch = BatchTelemetry(self.cores, self.physics) if telemetry == "batch" else None
        self.radio.update(self.physics.pos_ned_m, self.physics.alive)
        self._record_truth(self._t_s)  # sample 0: the state before any motion

    def _make_core(self, i: int, now_s: float, params: dict, signing_key) -> VehicleCore:
        """Boot the autopilot of row ``i`` at ``now_s`` (at start, and after a battery swap)."""
        core = VehicleCore(
            int(self.sysid_of_index[i]),
            self._personalities[i],
            now_s=now_s,
            physics=self.physics,
            index=i,
            params=params,
            signing_key=signing_key,
            network=int(self.network_of_index[i]),
            **self._core_kw,
        )
        for msg_id, hz in self._stream_rates_hz.items():
            core.set_stream_rate(int(msg_id), float(hz), now_s)
        return core

    # ------------------------------------------------------------------ identity / endpoints

    def identity(self, index: int) -> tuple[int, int]:
        """Array row -> (network, sysid)."""
        return int(self.network_of_index[index]), int(self.sysid_of_index[index])

    def index_of(self, network: int, sysid: int) -> int:
        """(network, sysid) -> array row (``KeyError`` if unknown)."""
        return self._index_of[(network, sysid)]

    def endpoint_of_index(self, index: int) -> int:
        return int(self.network_of_index[index]) if self.mux else int(index)

    def add_peer(self, endpoint: int, addr) -> None:
        """Add a permanent destination for everything ``endpoint`` sends (``udpout``)."""
        if addr not in self._static_peers[endpoint]:
            self._static_peers[endpoint].append(addr)
            self._learned[endpoint].pop(addr, None)
            self._rebuild_peers(endpoint)

    def _rebuild_peers(self, endpoint: int) -> None:
        self.peers[endpoint] = self._static_peers[endpoint] + list(self._learned[endpoint])
        if self._learned[endpoint]:
            self._endpoints_learned.add(endpoint)
        else:
            self._endpoints_learned.discard(endpoint)

    def _heard_from(self, endpoint: int, addr, now_s: float) -> None:
        """Learn ``addr`` as a peer of ``endpoint`` (SITL ``udpin``) or refresh it."""
        if addr in self._static_peers[endpoint]:
            return
        learned = self._learned[endpoint]
        if addr in learned:
            del learned[addr]  # re-insert at the end: most recently heard
            learned[addr] = now_s
            return
        if len(learned) >= self.max_peers:
            old = next(iter(learned))  # least recently heard
            del learned[old]
            self.stats["peers_evicted"] += 1
            self.log_limiter.log(
                now_s,
                "peer_evicted",
                logging.WARNING,
                "endpoint %d: more than %d peers, dropped %s for %s",
                endpoint,
                self.max_peers,
                old,
                addr,
            )
        learned[addr] = now_s
        self.stats["peers_learned"] += 1
        self.log_limiter.log(
            now_s, "peer_new", logging.INFO, "endpoint %d: new peer %s", endpoint, addr
        )
        self._rebuild_peers(endpoint)

    def expire_peers(self, now_s: float) -> int:
        """Forget learned peers silent for more than ``peer_timeout_s``; returns how many."""
        n = 0
        for endpoint in list(self._endpoints_learned):
            learned = self._learned[endpoint]
            stale = []
            for addr, t in learned.items():  # least recently heard first
                if now_s - t <= self.peer_timeout_s:
                    break
                stale.append(addr)
            if stale:
                for addr in stale:
                    del learned[addr]
                n += len(stale)
                self._rebuild_peers(endpoint)
        if n:
            self.stats["peers_expired"] += n
            self.log_limiter.log(
                now_s,
                "peer_expired",
                logging.INFO,
                "forgot %d peer(s) silent for more than %.0f s",
                n,
                self.peer_timeout_s,
            )
        return n

    # ------------------------------------------------------------------ sans-I/O surface

    @property
    def now_s(self) -> float:
        return self._t_s

    def receive_datagram(self, endpoint: int, data: bytes, addr, now_s: float) -> None:
        """A datagram from a GCS arrived at ``endpoint`` from ``addr``."""
        self.stats["datagrams_in"] += 1
        if addr is not None:
            self._heard_from(endpoint, addr, now_s)  # learn the GCS address (SITL udpin)
        if not self.mux:
            self._radio_to_vehicle(endpoint, data, addr, now_s)
            return
        # One parse per frame: the router reads the header and the target_system byte
        # (mavedge.codec.frame_target_system); the addressed core does the only full decode
        # (CRC, signature with its own key and streams, unpack).
        frames = wire.split_frames(data)
        if not frames and data:
            self.stats["unroutable"] += 1
            self.log_limiter.log(
                now_s,
                "unroutable",
                logging.WARNING,
                "endpoint %d: no MAVLink frame in a datagram from %s (%d so far)",
                endpoint,
                addr,
                self.stats["unroutable"],
            )
            return
        for frame in frames:
            target = wire.frame_target_system(frame)
            if target:
                i = self._index_of.get((endpoint, target))
                if i is None:
                    self.stats["unroutable"] += 1
                    self.log_limiter.log(
                        now_s,
                        "no_target",
                        logging.WARNING,
                        "endpoint %d: frame for unknown sysid %d from %s",
                        endpoint,
                        target,
                        addr,
                    )
                    continue
                self._radio_to_vehicle(i, frame, addr, now_s)
            else:
                self._broadcast_to_members(endpoint, frame, addr, now_s)

    def _broadcast_to_members(self, endpoint: int, frame: bytes, addr, now_s: float) -> None:
        """A frame for every vehicle of a network (target 0: the GCS heartbeat, ...): decoded
        once for all the cores without a signing key ("decode once, deliver many": a decode
        without a key depends on the bytes alone), by its own codec for a core with a key; the
        radio, the dead and delayed delivery as in :meth:`_radio_to_vehicle`, in member order."""
        shared = None
        cores = self.cores
        members = self._members[endpoint]
        # Who is alive and what the radio does to each, first: delivering a frame to one core
        # changes neither another's life nor the radio (Radio.transit_many: the same fates as
        # one transit per member, in member order).
        alive = [i for i in members if cores[i].alive]
        self.stats["dropped_dead"] += len(members) - len(alive)
        for i, delay in zip(alive, self.radio.transit_many(alive)):
            core = cores[i]
            if delay is None:
                self.stats["dropped_radio_in"] += 1
                continue
            if delay > 0:
                self._push_delayed(now_s + delay, ("in", i, frame, addr))
            elif core._codec.signing_enabled:
                core.receive_datagram(frame, addr, now_s)
            else:
                if shared is None:
                    shared = self._broadcast_codec.decode_datagram(frame)
                core.receive_decoded(shared, addr, now_s)

    def _radio_to_vehicle(self, i: int, data: bytes, addr, now_s: float) -> None:
        core = self.cores[i]
        if not core.alive:
            self.stats["dropped_dead"] += 1
            return
        delay = self.radio.transit(i)
        if delay is None:
            self.stats["dropped_radio_in"] += 1
            return
        if delay > 0:
            self._push_delayed(now_s + delay, ("in", i, data, addr))
        else:
            core.receive_datagram(data, addr, now_s)

    def _push_delayed(self, t_s: float, item) -> None:
        self._delay_seq += 1
        heapq.heappush(self._delayed, (t_s, self._delay_seq, item))

    def handle_timer(self, now_s: float) -> None:
        """One tick at vehicle time ``now_s`` (see module docstring)."""
        t0 = self._t_s
        dt = now_s - t0
        ph = self.physics
        # Deliver delayed inbound packets that are due.
        self._deliver_delayed(now_s, inbound=True)
        if now_s >= self._next_peer_sweep_s:
            self.expire_peers(now_s)
            self._next_peer_sweep_s = now_s + _PEER_SWEEP_PERIOD_S
        if dt > 0:
            for i, cause in self.attrition.step(t0, now_s, ph.alive, ~ph.landed & ph.armed):
                self.kill(i, now_s, cause)
        cores = self.cores
        for core in cores:
            if core.alive:
                core.update_autopilot(now_s)
        if dt > 0:
            was_landed = ph.landed.copy()
            ph.step(dt)
            if self.ground is not None:
                self._ground_contact(was_landed, now_s)
            ph.update_geodetic()
        self._t_s = max(t0, now_s)
        if ph.battery is not None:
            self._battery_ground_truth(now_s)
        if now_s - self._last_radio_s >= self.radio_period_s - 1e-9 or self._radio_dirty:
            self.radio.update(ph.pos_ned_m, ph.alive & self.powered)
            self._last_radio_s = now_s
            self._radio_dirty = False
        if now_s >= self._next_truth_s - 1e-9:
            self._record_truth(now_s)
            while self._next_truth_s <= now_s + 1e-9:
                self._next_truth_s += self.truth_period_s
        if self._batch is not None:
            self._batch.emit(now_s)
        events = self._events
        reference = self._batch is None
        for core in cores:
            if core.alive:
                if reference:
                    core.emit_telemetry(now_s)
                queue = core._events  # next_event() until empty, without a call per core
                while queue:
                    events.append(queue.popleft())
        self.stats["ticks"] += 1

    step = handle_timer

    def next_timer_s(self) -> float:
        t = self._t_s + self.tick_s
        if self._delayed:
            t = min(t, self._delayed[0][0])
        return t

    def datagrams_to_send(self, now_s: float) -> list[tuple[int, bytes, object]]:
        """Everything the vehicles send that the radio lets through: (endpoint, bytes, addr)."""
        out = []
        radio = self.radio
        mux = self.mux
        net = self.network_of_index
        cores = self.cores
        # Every core with frames queued, in index order (as a scan of all of them would find).
        dirty = self._out_dirty
        todo = sorted(i for i in dirty if cores[i]._out)
        dirty.clear()
        for i in todo:
            core = cores[i]
            dgrams = core.datagrams_to_send(now_s)
            if not core.alive:
                continue
            endpoint = int(net[i]) if mux else i
            for data, _ in dgrams:
                delay = radio.transit(i)
                if delay is None:
                    self.stats["dropped_radio_out"] += 1
                    continue
                if delay > 0:
                    self._push_delayed(now_s + delay, ("out", endpoint, data, None))
                    continue
                for addr in self.peers[endpoint]:
                    out.append((endpoint, data, addr))
        self._deliver_delayed(now_s, inbound=False, out=out)
        self.stats["datagrams_out"] += len(out)
        return out

    def _deliver_delayed(self, now_s: float, inbound: bool, out=None) -> None:
        if not self._delayed:
            return
        keep = []
        while self._delayed and self._delayed[0][0] <= now_s + 1e-12:
            item = heapq.heappop(self._delayed)
            kind, a, data, addr = item[2]
            if kind == "in" and inbound:
                core = self.cores[a]
                if core.alive and core._codec.signing_enabled:
                    core.receive_datagram(data, addr, now_s)
                elif core.alive:  # decoded once for every unsigned core it reaches
                    core.receive_decoded(self._decode_shared(data), addr, now_s)
            elif kind == "out" and not inbound:
                for peer in self.peers[a]:
                    out.append((a, data, peer))
            else:
                keep.append(item)
        for item in keep:
            heapq.heappush(self._delayed, item)

    def _decode_shared(self, data: bytes) -> wire.DecodeResult:
        """``data`` decoded by the broadcast codec (no key: the result depends on the bytes
        alone, and cores only read it), kept for the next core it reaches: a frame for every
        vehicle of a network reaches each member after its own hop delay, in another call of
        :meth:`_deliver_delayed`."""
        cache = self._decoded
        res = cache.get(data)
        if res is None:
            if len(cache) >= _DECODE_CACHE_SIZE:
                cache.clear()
            res = cache[data] = self._broadcast_codec.decode_datagram(data)
        return res

    def next_event(self):
        return self._events.popleft() if self._events else None

    # ------------------------------------------------------------------ attrition / truth

    # ------------------------------------------------------------------ batteries

    def _battery_ground_truth(self, now_s: float) -> None:
        """After the physics step: packs run empty (the vehicle is lost), the ground crew's swaps
        (power off, then boot with a full pack). docs/design/endurance.md §6.4."""
        ph = self.physics
        batt = ph.battery
        assert batt is not None  # called only with batteries on
        soc = batt.soc
        empty = ph.alive & self.powered & ph.armed & (soc <= 0.0)
        for i in np.flatnonzero(empty).tolist():
            self.kill(i, now_s, "battery_empty")
        swap = self.battery_swap
        if swap is None:
            return
        for i in np.flatnonzero(self.boot_at_s <= now_s + 1e-9).tolist():
            self._boot(i, now_s)
        soc = batt.soc  # after the boots (a booted vehicle has a full pack)
        due = ph.alive & self.powered & ~ph.armed & ph.landed & (soc < swap.used_below_frac)
        if not due.any():  # most ticks: nobody is on the ground with a used pack
            return
        home = np.array([c.home_ned_m for c in self.cores]).reshape(-1, 3)  # (N, 3) world NED
        at_home = np.hypot(*(ph.pos_ned_m[:, :2] - home[:, :2]).T) <= swap.home_radius_m
        for i in np.flatnonzero(due & at_home).tolist():
            self._power_off(i, now_s, now_s + swap.swap_time_s)

    def _power_off(self, i: int, now_s: float, boot_at_s: float) -> None:
        """The crew pulls the pack: the autopilot is off, silent, and no relay."""
        core = self.cores[i]
        core.kill()  # silent: nothing in, nothing out, no timers (the core is replaced at boot)
        self.powered[i] = False
        self.boot_at_s[i] = boot_at_s
        self.radio.active[i] = False
        self._radio_dirty = True
        net, sysid = self.identity(i)
        log.info("vehicle %d (sysid %d): battery swap until t=%.1f s", i, sysid, boot_at_s)
        self._events.append(ev.VehiclePoweredOff(sysid, now_s, net, i, boot_at_s))

    def _boot(self, i: int, now_s: float) -> None:
        """Power up with a full pack: a new autopilot (``time_boot_ms`` from 0, boot mode, EKF
        and arming wait of a fresh start) with the parameters and signing key it stored."""
        ph = self.physics
        assert ph.battery is not None  # swaps only with batteries
        old = self.cores[i]
        params = {name: old.params[name] for name in old.params.names()}
        # The key the vehicle stored (ArduPilot keeps it in its storage, PX4 on its SD card).
        key = old._codec._mav.signing.secret_key if old._codec.signing_enabled else None
        ph.battery.replace(i)
        ph.battery_frac = ph.battery.soc
        ph.hold(i)
        ph.vel_ned_m_s[i] = 0.0
        core = self._make_core(i, now_s, params, key)
        core._out_dirty = self._out_dirty
        self.cores[i] = core
        if self._batch is not None:
            self._batch.rebind(i, core)
        self.powered[i] = True
        self.boot_at_s[i] = np.inf
        self._radio_dirty = True
        net, sysid = self.identity(i)
        self._events.append(ev.VehicleBooted(sysid, now_s, net, i))

    def kill(self, index: int, now_s: float, cause: str = "scripted") -> None:
        """Lose vehicle ``index`` now: it freezes and goes silent forever."""
        core = self.cores[index]
        if not self.powered[index]:  # lost during a swap: it never boots again
            self.powered[index] = True
            self.boot_at_s[index] = np.inf
            core.alive = True
        if not core.alive:
            return
        core.kill()
        self.physics.alive[index] = False
        self.physics.vel_ned_m_s[index] = 0.0
        self.radio.active[index] = False  # silent at once; relays recomputed next tick
        self._radio_dirty = True
        net, sysid = self.identity(index)
        log.info(
            "vehicle %d (network %d, sysid %d) lost at t=%.2f s (%s)",
            index,
            net,
            sysid,
            now_s,
            cause,
        )
        self._events.append(ev.VehicleKilled(sysid, now_s, net, index, cause))

    def _ground_contact(self, was_landed: np.ndarray, now_s: float) -> None:
        """Keep every vehicle on or above the terrain after a physics step: one that came down
        on it stands on it; one flying that the ground rose through by more than
        :data:`vehicle_emu.terrain.CRASH_DEPTH_M`, or that touched it while moving faster than
        :data:`vehicle_emu.terrain.TOUCHDOWN_SPEED_H_M_S`, flew into it and is lost."""
        assert self.ground is not None  # terrain swarms only
        ph = self.physics
        ground = self.ground.ground_down_m(ph.pos_ned_m[:, :2])
        depth = ph.pos_ned_m[:, 2] - ground  # > 0: below the ground
        speed_h = np.hypot(ph.vel_ned_m_s[:, 0], ph.vel_ned_m_s[:, 1])
        hit = (depth > CRASH_DEPTH_M) | ((depth > 0) & (speed_h > TOUCHDOWN_SPEED_H_M_S))
        crash = hit & ph.alive & ph.armed & ~was_landed
        for i in np.flatnonzero(crash).tolist():
            self.stats["terrain_crashes"] += 1
            self.kill(i, now_s, "terrain")
        below = depth > 0
        ph.pos_ned_m[below, 2] = ground[below]
        ph.vel_ned_m_s[below, 2] = np.minimum(ph.vel_ned_m_s[below, 2], 0.0)
        ph.ground_down_m = ground
        if self.track_clearance:
            # Vehicles flying the station's targets (GUIDED / OFFBOARD), once they have been
            # clearance_from_agl_m up: not a take-off or a landing.
            agl = ground - ph.pos_ned_m[:, 2]
            guided = np.array([c._behaviour == "guided" for c in self.cores])
            flying = ph.alive & ph.armed & ~ph.landed & guided
            # A landing ends a flight: the next take-off (a relay relaunched after its battery
            # swap) is not counted until it is up again.
            self._risen &= flying
            self._risen |= flying & (agl >= self.clearance_from_agl_m)
            sel = flying & self._risen
            if sel.any():
                least, most = float(agl[sel].min()), float(agl[sel].max())
                self.least_agl_m = (
                    least if self.least_agl_m is None else min(self.least_agl_m, least)
                )
                self.highest_agl_m = (
                    most if self.highest_agl_m is None else max(self.highest_agl_m, most)
                )

    def sample_truth_from(self, t_s: float) -> None:
        """Put the truth sampling grid at ``t_s + k * truth_period_s`` (e.g. a mission's step
        grid); the first sample is taken at the first tick at or after ``t_s``."""
        self._next_truth_s = float(t_s)
        if self._t_s >= t_s - 1e-9:
            self._record_truth(self._t_s)
            self._next_truth_s = float(t_s) + self.truth_period_s
            while self._next_truth_s <= self._t_s + 1e-9:
                self._next_truth_s += self.truth_period_s

    def _record_truth(self, now_s: float) -> None:
        ph = self.physics
        tr = self.truth
        tr.t_s.append(now_s)
        tr.pos_ned_m.append(ph.pos_ned_m.copy())
        tr.alive.append(ph.alive.copy())
        tr.active.append(self.radio.active.copy())
        if self.task_pos_fn is not None:
            task_pos = np.asarray(self.task_pos_fn(now_s), dtype=float).reshape(-1, 2)
            if self.ground is not None:
                conn = self.ground.tasks_connected(task_pos, ph.pos_ned_m, self.radio.active)
            else:
                r = self.radio.config.radio_range_m
                conn = tasks_connected(task_pos, ph.pos_ned_m[:, :2], self.radio.active, r)
            tr.task_connected.append(conn)

    def task_uptime(self, zero_over_zero: str = "zero") -> tuple[float, float]:
        """Ground-truth (TU1, TU2) over the recorded samples (fractions)."""
        if not self.truth.task_connected:
            raise ValueError("no task connectivity recorded: construct Swarm with task_pos_fn")
        return task_uptime(np.asarray(self.truth.task_connected), zero_over_zero)

    def uptime_series(self):
        """Per-sample TU1/TU2 integrands (:class:`planner.metrics.UptimeSeries`)."""
        if not self.truth.task_connected:
            raise ValueError("no task connectivity recorded: construct Swarm with task_pos_fn")
        return uptime_series(np.asarray(self.truth.task_connected))

    @property
    def alive(self) -> np.ndarray:
        return self.physics.alive.copy()

    @property
    def active(self) -> np.ndarray:
        return self.radio.active.copy()

    def core_stats(self) -> dict[str, int]:
        """Sum of every core's counters."""
        total: dict[str, int] = {}
        for core in self.cores:
            for k, v in core.stats.as_dict().items():
                total[k] = total.get(k, 0) + v
        return total
