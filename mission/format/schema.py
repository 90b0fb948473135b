"""The mission: one typed definition of a deployment, in SI units, with every default.

A mission file (YAML, loaded by :mod:`mission.format.load`) describes where the base station is, which
vehicles fly, where the tasks (fire crews, rovers) are and how they move, what the radio reaches,
what kills drones, which planner runs, and for how long. The same file is played by the in-process
simulator, by the emulator + ground station, and on real links.

Rules (docs/design/architecture.md §5)
-------------------------
* This module is the **only** place where defaults live. The loader reads them from the dataclass
  fields; runners read them from the loaded :class:`Mission`.
* Every key carries its unit (``radio_range_m``, ``rate_per_s``, ``t_s``); angles are degrees
  (``lat_deg``) because humans write degrees (``Origin.lat_rad`` converts).
* Coordinates are named, never positional lists: ``{north_m: .., east_m: ..}`` in the local
  north-east frame centred on the base station (``origin``), or ``{lat_deg: .., lon_deg: ..}``.
* Sections that are "exactly one of" several forms (``vehicles``, ``spawn``, each task, each hazard
  zone's shape) are dataclasses whose alternatives are optional fields; :meth:`validate` (run by
  the loader) insists on exactly one. ``ONE_OF`` names the alternatives.
* Numeric limits are declared next to the field (``metadata``: ``ge``, ``gt``, ``le``, ``lt``,
  ``min_len``, ``max_len``); the loader enforces them and cross-field rules come from the
  ``validate()`` methods, so the schema is the single description of a valid mission.
* Length (over the ~600 lines this code base aims for): the schema is one document
  on purpose. Each dataclass sits next to its validation and its error messages, and the loader,
  the dumper and ``phireman mission new`` walk it as one tree; cut into files, a reader would
  have to assemble the one description of a valid mission from several.

Mapping the paper to the real world
-----------------------------------
The paper (RTNUA / PhiIREMAN) is written in dimensionless length units and discrete steps. A
mission states one choice of both:

* **length**: one paper length unit = ``L`` metres. The defaults use ``L = 50 m``, so the paper's
  r = 2 becomes ``radio.range_m = 100``, the ring of radius 1 (noise 0.2) becomes 50 m (10 m), and
  the S field [-5, 5]^2 becomes +-250 m. A planner working in paper units recovers
  ``L = radio.range_m / 2`` (:func:`paper_length_unit_m`).
* **time**: one paper step = ``run.control_period_s`` seconds (default 1 s), so the paper's speed
  v = 0.15 per step becomes ``0.15 * L / control_period_s`` = 7.5 m/s, the 200-step horizon becomes
  ``run.duration_s = 200``, and the per-step task random walk sigma becomes
  ``sigma_m_per_sqrt_s = sigma * L / sqrt(control_period_s)`` (5 m/sqrt(s)).
* **attrition**: a per-step loss probability ``p`` becomes a Poisson rate
  ``rate_per_s = -ln(1 - p) / control_period_s`` (:func:`rate_from_per_step`), so that the
  probability of surviving one control period is exactly ``1 - p``. 1 % per step at 1 s is
  0.01005 per second.

With these defaults, an empty mission file is the paper's S configuration (50 drones, 10 tasks)
without attrition, at the ArduPilot SITL home location. :func:`paper_mission` builds any of the
paper's configurations (used by ``phireman mission new``).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from typing import Any, Literal

__all__ = [
    "Mission",
    "Origin",
    "Position",
    "LocalPoint",
    "TrackPoint",
    "Vehicles",
    "FlightLimits",
    "EmulatedVehicles",
    "RealVehicles",
    "Spawn",
    "SpawnRing",
    "Task",
    "RandomWalk",
    "MavlinkSource",
    "TakSource",
    "TAK_URL_SCHEMES",
    "RandomTasks",
    "Radio",
    "Attrition",
    "ScriptedLoss",
    "HazardZone",
    "Circle",
    "PlannerSpec",
    "RunSpec",
    "BatterySpec",
    "BaseSpec",
    "EnduranceSpec",
    "OutputSpec",
    "PERSONALITIES",
    "BORDERS",
    "INFO_MODES",
    "MAX_DISTANCE_FROM_ORIGIN_M",
    "rate_from_per_step",
    "per_step_from_rate",
    "paper_length_unit_m",
    "paper_mission",
]

Personality = Literal["ardupilot", "px4", "mixed"]
Border = Literal["none", "clip", "reflect"]
#: planner.info: the information models of planner.info.INFO_MODELS (spelled out here because a
#: Literal is static and this module does not import the planner; tests/mission/test_station_info.py
#: checks the two agree).
InfoMode = Literal["central", "async"]

PERSONALITIES: tuple[str, ...] = ("ardupilot", "px4", "mixed")
BORDERS: tuple[str, ...] = ("none", "clip", "reflect")
INFO_MODES: tuple[str, ...] = typing.get_args(InfoMode)

#: Any position farther than this from the origin is refused (catches swapped lat/lon, typos), m.
MAX_DISTANCE_FROM_ORIGIN_M = 100_000.0

#: Mean Earth radius used for the small-area lat/lon <-> metres checks, m.
_EARTH_RADIUS_M = 6_371_008.8


def _f(default: Any = dataclasses.MISSING, *, factory: Any = dataclasses.MISSING, **limits: Any):
    """A dataclass field with its validation limits in ``metadata``."""
    if factory is not dataclasses.MISSING:
        return field(default_factory=factory, metadata=limits)
    return field(default=default, metadata=limits)


def _fmt(x: Any) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x) if isinstance(x, str) else str(x)


class _Section:
    """Mixin: ``validate()`` returns cross-field problems as ``(relative path, message)``."""

    ONE_OF: tuple[str, ...] = ()
    """Names of fields of which exactly one must be set (empty: no such rule)."""

    def validate(self) -> list[tuple[str, str]]:
        if not self.ONE_OF:
            return []
        given = [name for name in self.ONE_OF if getattr(self, name) is not None]
        if len(given) == 1:
            return []
        what = f"got {', '.join(given)}" if given else "got none"
        return [("", f"must have exactly one of {', '.join(self.ONE_OF)}; {what}")]

    def set_alternative(self) -> str:
        """Name of the alternative that is set (for ``ONE_OF`` sections)."""
        for name in self.ONE_OF:
            if getattr(self, name) is not None:
                return name
        raise ValueError(f"{type(self).__name__}: none of {self.ONE_OF} is set")


# --------------------------------------------------------------------------------------------
# Conversions


def rate_from_per_step(p: float, control_period_s: float) -> float:
    """Poisson loss rate (1/s) equivalent to a per-step loss probability ``p``.

    ``rate = -ln(1 - p) / control_period_s``: the probability of surviving one period is ``1 - p``.
    """
    if not 0.0 <= p < 1.0:
        raise ValueError(f"p must be in [0, 1), got {p}")
    if not control_period_s > 0:
        raise ValueError(f"control_period_s must be > 0, got {control_period_s}")
    return -math.log1p(-p) / control_period_s


def per_step_from_rate(rate_per_s: float, control_period_s: float) -> float:
    """Per-step loss probability equivalent to a Poisson rate: ``1 - exp(-rate * period)``."""
    if not rate_per_s >= 0:
        raise ValueError(f"rate_per_s must be >= 0, got {rate_per_s}")
    if not control_period_s > 0:
        raise ValueError(f"control_period_s must be > 0, got {control_period_s}")
    return -math.expm1(-rate_per_s * control_period_s)


def paper_length_unit_m(radio_range_m: float) -> float:
    """Metres per paper length unit, given the drones' radio range (the paper's r = 2 units)."""
    return radio_range_m / 2.0


def _approx_local_m(origin: Origin, lat_deg: float, lon_deg: float) -> tuple[float, float]:
    """(north_m, east_m) of a lat/lon relative to the origin, equirectangular (validation only)."""
    north = math.radians(lat_deg - origin.lat_deg) * _EARTH_RADIUS_M
    dlon = (lon_deg - origin.lon_deg + 180.0) % 360.0 - 180.0
    east = math.radians(dlon) * _EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))
    return north, east


# --------------------------------------------------------------------------------------------
# Coordinates


@dataclass(frozen=True, kw_only=True)
class Origin(_Section):
    """The base station: the origin of the local north-east frame."""

    lat_deg: float = _f(-35.363261, ge=-90.0, le=90.0)
    """Latitude, degrees (WGS84). Default: the ArduPilot SITL home (CMAC, Canberra)."""
    lon_deg: float = _f(149.165230, ge=-180.0, le=180.0)
    """Longitude, degrees (WGS84)."""
    alt_amsl_m: float = _f(584.0, ge=-500.0, le=9000.0)
    """Ground altitude of the base station above mean sea level, metres."""

    @property
    def lat_rad(self) -> float:
        """Latitude, radians."""
        return math.radians(self.lat_deg)

    @property
    def lon_rad(self) -> float:
        """Longitude, radians."""
        return math.radians(self.lon_deg)

    def to_local_m(
        self, lat_deg: float, lon_deg: float, alt_m: float | None = None
    ) -> tuple[float, float]:
        """(north_m, east_m) of a WGS84 point in this origin's local frame, metres."""
        import pymap3d  # lazy: only runners converting geographic tasks pay for it

        n, e, _d = pymap3d.geodetic2ned(
            lat_deg,
            lon_deg,
            self.alt_amsl_m if alt_m is None else alt_m,
            self.lat_deg,
            self.lon_deg,
            self.alt_amsl_m,
        )
        return float(n), float(e)

    def to_geo_deg(self, north_m: float, east_m: float) -> tuple[float, float]:
        """(lat_deg, lon_deg) of a local point at the origin's altitude."""
        import pymap3d

        lat, lon, _h = pymap3d.ned2geodetic(
            north_m, east_m, 0.0, self.lat_deg, self.lon_deg, self.alt_amsl_m
        )
        return float(lat), float(lon)


@dataclass(frozen=True, kw_only=True)
class LocalPoint(_Section):
    """A point in the local frame centred on the base station."""

    north_m: float = _f()
    """Metres north of the base station."""
    east_m: float = _f()
    """Metres east of the base station."""


@dataclass(frozen=True, kw_only=True)
class Position(_Section):
    """A point given either locally (``north_m`` + ``east_m``) or geographically (``lat_deg`` +
    ``lon_deg`` [+ ``alt_m``])."""

    north_m: float | None = None
    """Metres north of the base station (local form)."""
    east_m: float | None = None
    """Metres east of the base station (local form)."""
    lat_deg: float | None = _f(None, ge=-90.0, le=90.0)
    """Latitude, degrees (geographic form)."""
    lon_deg: float | None = _f(None, ge=-180.0, le=180.0)
    """Longitude, degrees (geographic form)."""
    alt_m: float | None = None
    """Altitude above mean sea level, metres (geographic form, optional; informational)."""

    @property
    def is_geo(self) -> bool:
        return self.lat_deg is not None or self.lon_deg is not None

    def validate(self) -> list[tuple[str, str]]:
        local = (self.north_m is not None, self.east_m is not None)
        geo = (self.lat_deg is not None, self.lon_deg is not None)
        if any(local) and (any(geo) or self.alt_m is not None):
            return [("", "give either north_m/east_m or lat_deg/lon_deg, not both")]
        if any(local) and not all(local):
            return [("", f"missing {'east_m' if local[0] else 'north_m'}")]
        if any(geo) and not all(geo):
            return [("", f"missing {'lon_deg' if geo[0] else 'lat_deg'}")]
        if not any(local) and not any(geo):
            return [("", "a position needs north_m and east_m, or lat_deg and lon_deg")]
        return []

    def local_m(self, origin: Origin) -> tuple[float, float]:
        """(north_m, east_m) in the mission frame."""
        if self.is_geo:
            assert self.lat_deg is not None and self.lon_deg is not None  # is_geo
            return origin.to_local_m(self.lat_deg, self.lon_deg, self.alt_m)
        assert self.north_m is not None and self.east_m is not None  # validated
        return float(self.north_m), float(self.east_m)


@dataclass(frozen=True, kw_only=True)
class TrackPoint(Position):
    """One vertex of a timed track: a :class:`Position` plus its time."""

    t_s: float = _f(ge=0.0)
    """Time since the start of the run at which the task is at this position, seconds."""


# --------------------------------------------------------------------------------------------
# Vehicles


@dataclass(frozen=True, kw_only=True)
class SpawnRing(_Section):
    """Drones start evenly spaced on a ring around the base, plus Gaussian noise (paper §5.5)."""

    radius_m: float = _f(50.0, ge=0.0)
    """Ring radius, metres (paper: 1 unit)."""
    noise_m: float = _f(10.0, ge=0.0)
    """Standard deviation of the per-axis Gaussian noise on each start position, metres (0.2)."""


@dataclass(frozen=True, kw_only=True)
class Spawn(_Section):
    """Where emulated drones start: exactly one of ``ring`` or ``positions``."""

    ONE_OF = ("ring", "positions")

    ring: SpawnRing | None = None
    """Evenly spaced ring around the base station."""
    positions: tuple[LocalPoint, ...] | None = _f(None, min_len=1)
    """Explicit start positions, one per drone, in vehicle order."""


@dataclass(frozen=True, kw_only=True)
class FlightLimits(_Section):
    """Flight parameters shared by emulated and real vehicles."""

    max_speed_m_s: float = _f(7.5, gt=0.0, le=100.0)
    """Horizontal speed limit the planner respects, m/s (paper: 0.15 unit per step)."""
    climb_rate_m_s: float = _f(2.5, gt=0.0, le=50.0)
    """Vertical speed for take-off and layer changes, m/s (ArduPilot WPNAV_SPEED_UP default)."""
    descent_rate_m_s: float | None = _f(None, gt=0.0, le=50.0)
    """Vertical speed down, m/s, written to the vehicles with the other limits (ArduPilot
    ``WPNAV_SPEED_DN``, PX4 ``MPC_Z_VEL_MAX_DN``, at most 4 m/s on PX4); over terrain the station
    plans its descents at it (docs/terrain.md §6.2). None: the firmware's own (1.5 m/s by
    default on both)."""
    cruise_alt_m: float = _f(30.0, gt=0.0, le=10_000.0)
    """Altitude of the lowest flight layer above the base station, metres."""
    layer_spacing_m: float = _f(5.0, ge=0.0, le=1000.0)
    """Vertical spacing between flight layers (collision separation), metres."""
    n_layers: int = _f(3, ge=1, le=100)
    """Number of flight layers; drone ``i`` flies at ``cruise_alt_m + (i % n_layers) * spacing``."""

    def validate(self) -> list[tuple[str, str]]:
        if self.n_layers > 1 and self.layer_spacing_m <= 0:
            return [
                (
                    "layer_spacing_m",
                    f"must be > 0 when n_layers > 1, got {_fmt(self.layer_spacing_m)}",
                )
            ]
        return []

    def layer_alt_m(self, index: int) -> float:
        """Cruise altitude of vehicle ``index`` above the base station, metres."""
        return self.cruise_alt_m + (index % self.n_layers) * self.layer_spacing_m


@dataclass(frozen=True, kw_only=True)
class EmulatedVehicles(FlightLimits):
    """Drones played by the MAVLink emulator (or by the in-process simulator)."""

    count: int = _f(50, ge=1, le=10_000)
    """Number of drones (paper S: 50). MAVLink system ids are 1..count."""
    personality: Personality = "ardupilot"
    """Autopilot the emulator imitates: 'ardupilot', 'px4', or 'mixed' (alternating)."""
    spawn: Spawn = _f(factory=lambda: Spawn(ring=SpawnRing()))
    """Start positions (default: the paper's ring)."""
    radio_range_m: float | None = _f(None, gt=0.0)
    """Range of the emulated radios, metres; unset means ``radio.range_m`` (filled by the loader)."""

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        if self.spawn.positions is not None and len(self.spawn.positions) != self.count:
            problems.append(
                (
                    "spawn.positions",
                    f"{len(self.spawn.positions)} positions for count {self.count}; "
                    "give one per drone",
                )
            )
        return problems


def _connection_problem(text: str) -> str | None:
    """None if ``text`` is a connection string the ground station accepts, else why not."""
    from gcs.connection import parse_connection  # the one parser of connection strings

    try:
        parse_connection(text)
    except ValueError as exc:
        return str(exc)
    return None


@dataclass(frozen=True, kw_only=True)
class RealVehicles(FlightLimits):
    """Real vehicles (ArduPilot or PX4) reached over MAVLink links."""

    connections: tuple[str, ...] = _f(min_len=1, max_len=1000)
    """pymavlink connection strings, e.g. 'udpin:0.0.0.0:14550', 'tcp:10.0.0.2:5760',
    '/dev/ttyUSB0,57600'. Vehicles are numbered in the order their heartbeats are first heard."""
    signing_key_hex: str | None = None
    """MAVLink 2 signing key: 64 hex digits (32 bytes). Unset: unsigned links."""
    sysids: tuple[int, ...] | None = None
    """The MAVLink system ids of this mission's vehicles: on every link only these become
    vehicles, anything else is refused and counted (phantoms from a noisy radio, another
    operator's drones). Unset: any autopilot heard, up to ``phireman fly --vehicles N``."""

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        if self.sysids is not None:
            bad = [s for s in self.sysids if not 1 <= s <= 254]
            if bad:
                problems.append(("sysids", f"system ids must be in 1..254, got {bad}"))
            if len(set(self.sysids)) != len(self.sysids):
                problems.append(("sysids", "duplicate system ids"))
        for i, conn in enumerate(self.connections):
            msg = _connection_problem(conn)
            if msg:
                problems.append((f"connections[{i}]", msg))
        if len(set(self.connections)) != len(self.connections):
            problems.append(("connections", "duplicate connection strings"))
        key = self.signing_key_hex
        if key is not None:
            if len(key) != 64:
                problems.append(
                    (
                        "signing_key_hex",
                        f"must be 64 hex digits (32 bytes), got {len(key)} characters",
                    )
                )
            elif any(c not in "0123456789abcdefABCDEF" for c in key):
                problems.append(("signing_key_hex", "must contain only hex digits 0-9 a-f"))
        return problems


@dataclass(frozen=True, kw_only=True)
class Vehicles(_Section):
    """The swarm: exactly one of ``emulated`` or ``real``."""

    ONE_OF = ("emulated", "real")

    emulated: EmulatedVehicles | None = None
    """Emulated (or simulated) drones."""
    real: RealVehicles | None = None
    """Real vehicles over MAVLink."""

    @property
    def limits(self) -> FlightLimits:
        """The flight limits of whichever kind is set."""
        limits = self.emulated if self.emulated is not None else self.real
        assert limits is not None  # exactly one kind is set (validated)
        return limits

    @property
    def count(self) -> int:
        """Number of vehicles (for real links: the number of connections)."""
        if self.emulated is not None:
            return self.emulated.count
        return len(self.real.connections) if self.real is not None else 0


# --------------------------------------------------------------------------------------------
# Tasks


@dataclass(frozen=True, kw_only=True)
class RandomWalk(_Section):
    """A task doing a seeded Gaussian random walk (Brownian motion sampled every control period)."""

    start: Position = _f()
    """Start position."""
    sigma_m_per_sqrt_s: float = _f(5.0, ge=0.0, le=1000.0)
    """Per-axis standard deviation after one second, m/sqrt(s); over a period dt the per-axis step
    has std ``sigma * sqrt(dt)`` (paper: 0.1 unit per step)."""
    border: Border = "none"
    """At the edge of the square field: 'none' (unbounded), 'clip' or 'reflect'."""
    field_half_width_m: float | None = _f(None, gt=0.0)
    """Half-width of the square field centred on the base, metres; required unless border is 'none'."""

    def validate(self) -> list[tuple[str, str]]:
        if self.border != "none" and self.field_half_width_m is None:
            return [("field_half_width_m", f"required when border is {self.border!r}")]
        return []


@dataclass(frozen=True, kw_only=True)
class MavlinkSource(_Section):
    """A task whose position comes live from a MAVLink system (a tracker carried by a crew)."""

    sysid: int = _f(ge=1, le=255)
    """MAVLink system id whose GLOBAL_POSITION_INT gives the task position."""
    connection: str | None = None
    """Connection string to listen on; unset: the link the vehicles use."""

    def validate(self) -> list[tuple[str, str]]:
        if self.connection is not None:
            msg = _connection_problem(self.connection)
            if msg:
                return [("connection", msg)]
        return []


#: How ``tak.url`` and ``phireman fly --tak`` may start (pytak's COT_URL schemes; ``+ro`` read
#: only, ``+wo`` write only).
TAK_URL_SCHEMES: tuple[str, ...] = (
    "udp",
    "udp+ro",
    "udp+wo",
    "udp+broadcast",
    "tcp",
    "tcp+ro",
    "tcp+wo",
    "tls",
    "tls+ro",
    "tls+wo",
)


def tak_url_problem(text: str) -> str | None:
    """None if ``text`` is a TAK connection this station opens, else why not."""
    from urllib.parse import urlparse

    try:
        u = urlparse(text)
        port = u.port
    except ValueError as exc:
        return f"{text!r} is not a URL: {exc}"
    if u.scheme.lower() not in TAK_URL_SCHEMES:
        return (
            f"{text!r}: scheme {u.scheme or '(none)'!r} is not one of "
            f"{', '.join(TAK_URL_SCHEMES)} (e.g. udp://239.2.3.1:6969, tls://tak.example:8089)"
        )
    if not u.hostname or port is None:
        return f"{text!r} needs a host and a port, e.g. udp://239.2.3.1:6969"
    return None


@dataclass(frozen=True, kw_only=True)
class TakSource(_Section):
    """A crew whose position comes live from its TAK phone (ATAK, iTAK, WinTAK): the Cursor-on-
    Target position reports of one TAK contact, given by exactly one of ``uid``, ``callsign``,
    ``callsign_pattern`` or ``callsign_regex`` (docs/tak.md). A report past its CoT ``stale``
    time makes the crew unknown: shown and planned as not connected until it reports again."""

    ONE_OF = ("uid", "callsign", "callsign_pattern", "callsign_regex")

    uid: str | None = None
    """The contact's CoT uid (ATAK: ANDROID-<device id>)."""
    callsign: str | None = None
    """The contact's callsign (case-insensitive)."""
    callsign_pattern: str | None = None
    """A glob (``ENGINE-*``, case-insensitive): each new contact matching it takes a free slot."""
    callsign_regex: str | None = None
    """A regular expression the whole callsign must match (Python ``re``), as the pattern."""
    slots: int = _f(1, ge=1, le=1000)
    """With a pattern: how many crews may join by it (task columns kept for them; an empty slot
    is an unknown crew). With ``uid`` / ``callsign``: 1."""
    url: str | None = None
    """Where the reports come from (a pytak COT_URL: ``udp://239.2.3.1:6969``, ``tcp://H:P``,
    ``tls://H:P``); unset: every ``phireman fly --tak`` URL, or ATAK's mesh SA multicast
    udp://239.2.3.1:6969 when none is given."""

    @property
    def is_pattern(self) -> bool:
        return self.callsign_pattern is not None or self.callsign_regex is not None

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        for key in ("uid", "callsign", "callsign_pattern", "callsign_regex"):
            v = getattr(self, key)
            if v is not None and not v.strip():
                problems.append((key, "must not be empty"))
        if self.callsign_regex is not None:
            import re

            try:
                re.compile(self.callsign_regex)
            except re.error as exc:
                problems.append(
                    (
                        "callsign_regex",
                        f"{self.callsign_regex!r} is not a regular expression: {exc}",
                    )
                )
        if self.slots != 1 and not self.is_pattern:
            problems.append(
                ("slots", f"only with callsign_pattern or callsign_regex (got {self.slots})")
            )
        if self.url is not None:
            msg = tak_url_problem(self.url)
            if msg:
                problems.append(("url", msg))
        return problems


@dataclass(frozen=True, kw_only=True)
class RandomTasks(_Section):
    """A generator of ``count`` tasks, uniform in the square field, each doing a random walk
    (the paper's tasks, §5.5). Placement and walks are drawn from the run's seed."""

    count: int = _f(10, ge=1, le=10_000)
    """Number of tasks (paper S: 10)."""
    field_half_width_m: float = _f(250.0, gt=0.0)
    """Tasks start uniform in [-w, w]^2 around the base, metres (paper S: 5 units)."""
    sigma_m_per_sqrt_s: float = _f(5.0, ge=0.0, le=1000.0)
    """Random-walk per-axis standard deviation after one second, m/sqrt(s) (paper: 0.1 per step)."""
    border: Border = "clip"
    """At the field edge: 'none', 'clip' (paper reproduction default) or 'reflect'."""


@dataclass(frozen=True, kw_only=True)
class Task(_Section):
    """One entry of ``tasks``: exactly one of ``track``, ``random_walk``, ``mavlink``, ``tak`` or
    the generator ``random``; ``name`` is an optional label."""

    ONE_OF = ("track", "random_walk", "mavlink", "tak", "random")

    name: str | None = None
    """Label for plots and logs (for ``random``: a prefix)."""
    track: tuple[TrackPoint, ...] | None = _f(None, min_len=1, max_len=100_000)
    """Piecewise-linear timed track; before the first / after the last time the task holds still."""
    random_walk: RandomWalk | None = None
    """Seeded random walk."""
    mavlink: MavlinkSource | None = None
    """Live position from a MAVLink system."""
    tak: TakSource | None = None
    """Live position from a crew's TAK phone (Cursor on Target)."""
    random: RandomTasks | None = None
    """Generator of N random-walking tasks."""

    @property
    def kind(self) -> str:
        """'track', 'random_walk', 'mavlink', 'tak' or 'random'."""
        return self.set_alternative()

    @property
    def count(self) -> int:
        """Number of tasks this entry stands for."""
        if self.random is not None:
            return self.random.count
        return self.tak.slots if self.tak is not None else 1

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        if self.track is not None:
            for i in range(1, len(self.track)):
                a, b = self.track[i - 1].t_s, self.track[i].t_s
                if not b > a:
                    problems.append(
                        (f"track[{i}].t_s", f"times must increase (got {_fmt(b)} after {_fmt(a)})")
                    )
        return problems

    def track_position_m(self, t_s: float, origin: Origin) -> tuple[float, float]:
        """Position of a ``track`` task at time ``t_s`` (linear between vertices), metres."""
        if self.track is None:
            raise ValueError("not a track task")
        pts = [(p.t_s, *p.local_m(origin)) for p in self.track]
        if t_s <= pts[0][0]:
            return pts[0][1], pts[0][2]
        for (t0, n0, e0), (t1, n1, e1) in zip(pts, pts[1:]):
            if t_s <= t1:
                a = (t_s - t0) / (t1 - t0)
                return n0 + a * (n1 - n0), e0 + a * (e1 - e0)
        return pts[-1][1], pts[-1][2]


# --------------------------------------------------------------------------------------------
# Radio, attrition


@dataclass(frozen=True, kw_only=True)
class RadioLink(_Section):
    """A radio's link budget, clearance rule and antenna heights (``radio.model: terrain``;
    docs/terrain.md §2). Defaults: a common 2.4 GHz mesh radio (the planner's
    :class:`planner.terrain.LinkBudget` has the same)."""

    frequency_mhz: float = _f(2400.0, gt=0.0, le=100_000.0)
    """Carrier frequency, MHz."""
    tx_power_dbm: float = _f(20.0, ge=-30.0, le=50.0)
    """Transmit power, dBm."""
    tx_gain_dbi: float = _f(2.0, ge=-20.0, le=40.0)
    """Transmit antenna gain, dBi."""
    rx_gain_dbi: float = _f(2.0, ge=-20.0, le=40.0)
    """Receive antenna gain, dBi."""
    sensitivity_dbm: float = _f(-90.0, ge=-150.0, le=0.0)
    """Receiver sensitivity, dBm."""
    fade_margin_db: float = _f(10.0, ge=0.0, le=60.0)
    """Margin kept for fading, dB."""
    fresnel_clear_fraction: float = _f(0.6, ge=0.0, le=1.0)
    """Fraction of the first Fresnel zone the terrain must stay out of."""
    k_factor: float = _f(4.0 / 3.0, gt=0.0, le=100.0)
    """Effective earth radius factor."""
    crew_antenna_agl_m: float = _f(1.5, ge=0.0, le=100.0)
    """Height of a crew's radio above the ground, metres."""
    base_antenna_agl_m: float = _f(1.5, ge=0.0, le=100.0)
    """Height of the base's antenna above the ground, metres."""

    def link_budget(self):
        """The :class:`planner.terrain.LinkBudget` of this section."""
        from planner.terrain import LinkBudget

        return LinkBudget(
            frequency_hz=self.frequency_mhz * 1e6,
            tx_power_dbm=self.tx_power_dbm,
            tx_gain_dbi=self.tx_gain_dbi,
            rx_gain_dbi=self.rx_gain_dbi,
            sensitivity_dbm=self.sensitivity_dbm,
            fade_margin_db=self.fade_margin_db,
            fresnel_clear_fraction=self.fresnel_clear_fraction,
            k_factor=self.k_factor,
        )

    def validate(self) -> list[tuple[str, str]]:
        budget = (
            self.tx_power_dbm
            + self.tx_gain_dbi
            + self.rx_gain_dbi
            - self.sensitivity_dbm
            - self.fade_margin_db
        )
        if budget <= 0:
            return [("", f"the link budget is {_fmt(budget)} dB: no link closes")]
        return []


RadioModel = Literal["disc", "terrain"]


@dataclass(frozen=True, kw_only=True)
class Radio(_Section):
    """The radio model the planner plans for and the simulator applies."""

    model: RadioModel = "disc"
    """'disc' (the paper: links within ``range_m``) or 'terrain' (links need line of sight over
    the mission's ``terrain`` and a closing link ``budget``; docs/terrain.md)."""
    link: RadioLink | None = None
    """The link budget and antenna heights (``model: terrain``); unset: the defaults of
    :class:`RadioLink`."""

    @property
    def terrain_link(self) -> RadioLink:
        """``link``, or the defaults."""
        return self.link if self.link is not None else RadioLink()

    range_m: float = _f(100.0, gt=0.0)
    """Drone-to-drone (and drone-to-task) communication radius r, metres (paper: 2 units)."""
    base_range_m: float = _f(100.0, gt=0.0)
    """Base-station radius R, metres; a drone reaches the base within min(R, r) (paper: R = r)."""
    latency_s: float = _f(0.0, ge=0.0, le=60.0)
    """Delay per radio hop, seconds."""
    loss_prob: float = _f(0.0, ge=0.0, le=1.0)
    """Independent probability that one message on one hop is lost."""


# --------------------------------------------------------------------------------------------
# Terrain (docs/terrain.md)


@dataclass(frozen=True, kw_only=True)
class RidgeSpec(_Section):
    """A ridge along a polyline, raised-cosine flanks."""

    path: tuple[LocalPoint, ...] = _f(min_len=1, max_len=1000)
    """The crest line."""
    height_m: float = _f(ge=-5000.0, le=5000.0)
    """Height of the crest above the plane, metres."""
    half_width_m: float = _f(gt=0.0)
    """Distance from the crest at which the flanks reach the plane, metres."""


@dataclass(frozen=True, kw_only=True)
class CanyonSpec(_Section):
    """A river canyon along a polyline: a flat floor and straight walls."""

    path: tuple[LocalPoint, ...] = _f(min_len=1, max_len=1000)
    """The river."""
    depth_m: float = _f(gt=0.0, le=5000.0)
    """Depth of the floor below the rims, metres."""
    floor_half_width_m: float = _f(ge=0.0)
    """Half width of the floor, metres."""
    rim_half_width_m: float = _f(gt=0.0)
    """Distance from the river to each rim, metres (more than the floor's half width)."""

    def validate(self) -> list[tuple[str, str]]:
        if not self.rim_half_width_m > self.floor_half_width_m:
            return [("rim_half_width_m", "must be more than floor_half_width_m")]
        return []


@dataclass(frozen=True, kw_only=True)
class HillSpec(_Section):
    """A round (Gaussian) hill; a negative height makes a basin."""

    center: LocalPoint = _f()
    """The summit."""
    height_m: float = _f(ge=-5000.0, le=5000.0)
    """Height above the plane, metres."""
    radius_m: float = _f(gt=0.0)
    """The Gaussian's sigma, metres."""


@dataclass(frozen=True, kw_only=True)
class SyntheticTerrain(_Section):
    """A scene of a few parametric features on the plane through the base's ground
    (``origin.alt_amsl_m``)."""

    half_width_m: float = _f(1500.0, gt=0.0, le=50_000.0)
    """The grid covers [-w, w]^2 around the base, metres."""
    spacing_m: float = _f(10.0, gt=0.0, le=1000.0)
    """Post spacing, metres."""
    ridges: tuple[RidgeSpec, ...] = ()
    """Ridges."""
    canyons: tuple[CanyonSpec, ...] = ()
    """River canyons."""
    hills: tuple[HillSpec, ...] = ()
    """Hills and basins."""

    def validate(self) -> list[tuple[str, str]]:
        if (2 * self.half_width_m / self.spacing_m + 1) ** 2 > 25_000_000:
            return [("spacing_m", "more than 25 million posts; use a coarser spacing")]
        return []


@dataclass(frozen=True, kw_only=True)
class GeoTiffTerrain(_Section):
    """A digital elevation model in a GeoTIFF (USGS 3DEP, SRTM, ...), in any CRS: resampled onto
    a grid in the mission's local frame (docs/terrain.md §4)."""

    path: str = _f()
    """The file (absolute, or relative to the working directory)."""
    half_width_m: float = _f(2000.0, gt=0.0, le=50_000.0)
    """The local grid covers [-w, w]^2 around the base, metres."""
    spacing_m: float = _f(10.0, gt=0.0, le=1000.0)
    """Post spacing of the local grid, metres."""
    band: int = _f(1, ge=1)
    """The raster band of heights."""


@dataclass(frozen=True, kw_only=True)
class TerrainSpec(_Section):
    """The ground: a synthetic scene or a GeoTIFF; and how high drones may fly over it."""

    ONE_OF = ("synthetic", "geotiff")

    synthetic: SyntheticTerrain | None = None
    """A scene of parametric features."""
    geotiff: GeoTiffTerrain | None = None
    """A digital elevation model."""
    cruise_agl_m: float = _f(100.0, gt=0.0, le=10_000.0)
    """Height above ground terrain-aware drones hold, metres."""
    ceiling_agl_m: float = _f(120.0, gt=0.0, le=10_000.0)
    """The highest a drone may fly above the ground, metres (400 ft)."""
    clearance_m: float = _f(15.0, ge=0.0, le=1000.0)
    """The least height above the ground along any terrain-aware flight, metres."""

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        if not self.clearance_m <= self.cruise_agl_m <= self.ceiling_agl_m:
            problems.append(("cruise_agl_m", "must lie between clearance_m and ceiling_agl_m"))
        return problems


@dataclass(frozen=True, kw_only=True)
class ScriptedLoss(_Section):
    """A drone lost at a given time, whatever happens."""

    vehicle: int = _f(ge=0)
    """Index of the vehicle (0-based, in vehicle order; emulated sysid = index + 1)."""
    t_s: float = _f(ge=0.0)
    """Time of the loss since the start of the run, seconds."""


@dataclass(frozen=True, kw_only=True)
class Circle(_Section):
    """A disc in the local frame."""

    center: LocalPoint = _f()
    """Centre of the disc."""
    radius_m: float = _f(gt=0.0)
    """Radius, metres."""


def _polygon_area_m2(points: tuple[LocalPoint, ...]) -> float:
    s = 0.0
    for a, b in zip(points, points[1:] + points[:1]):
        s += a.east_m * b.north_m - b.east_m * a.north_m
    return abs(s) / 2.0


@dataclass(frozen=True, kw_only=True)
class HazardZone(_Section):
    """A region where drones are lost at an extra rate during a time window (the paper's
    "geographically localized attrition"). Shape: exactly one of ``circle`` or ``polygon``."""

    ONE_OF = ("circle", "polygon")

    circle: Circle | None = None
    """A disc."""
    polygon: tuple[LocalPoint, ...] | None = _f(None, min_len=3, max_len=10_000)
    """A simple polygon, vertices in order (closing edge implied)."""
    rate_per_s: float = _f(0.05, ge=0.0, le=1000.0)
    """Extra loss rate of a drone inside the zone, 1/s (added to ``attrition.rate_per_s``)."""
    start_s: float = _f(0.0, ge=0.0)
    """Zone becomes active at this time since the start of the run, seconds."""
    end_s: float | None = _f(None, gt=0.0)
    """Zone stops at this time, seconds; unset: active until the end of the run."""

    def validate(self) -> list[tuple[str, str]]:
        problems = super().validate()
        if self.end_s is not None and not self.end_s > self.start_s:
            problems.append(
                (
                    "",
                    f"end_s must be after start_s (got end_s {_fmt(self.end_s)}, "
                    f"start_s {_fmt(self.start_s)})",
                )
            )
        if (
            self.polygon is not None
            and len(self.polygon) >= 3
            and _polygon_area_m2(self.polygon) <= 0
        ):
            problems.append(("polygon", "has zero area (vertices are collinear)"))
        return problems

    def contains_ne(self, pos_ne_m: Any) -> Any:
        """(N,) bool: which local points (north, east), an (N, 2) array in metres, lie in the zone
        (ignores the time window). The one point-in-zone test of the code base: even-odd ray
        casting over the polygon's edges, vectorised over the points."""
        import numpy as np

        pos = np.asarray(pos_ne_m, dtype=float).reshape(-1, 2)
        north, east = pos[:, 0], pos[:, 1]
        if self.circle is not None:
            c = self.circle.center
            return np.hypot(north - c.north_m, east - c.east_m) <= self.circle.radius_m
        inside = np.zeros(len(pos), dtype=bool)
        pts = self.polygon
        assert pts is not None  # a circle or a polygon (validated)
        for a, b in zip(pts, pts[1:] + pts[:1]):  # edges; an edge crossed by the ray flips
            crosses = (a.north_m > north) != (b.north_m > north)
            with np.errstate(divide="ignore", invalid="ignore"):
                x = a.east_m + (north - a.north_m) * (b.east_m - a.east_m) / (b.north_m - a.north_m)
            inside ^= crosses & (east < x)
        return inside

    def contains(self, north_m: float, east_m: float) -> bool:
        """Whether one local point is inside the zone (ignores the time window)."""
        return bool(self.contains_ne([[north_m, east_m]])[0])

    def active(self, t_s: float) -> bool:
        """Whether the zone is active at time ``t_s``."""
        return t_s >= self.start_s and (self.end_s is None or t_s < self.end_s)


@dataclass(frozen=True, kw_only=True)
class Attrition(_Section):
    """What destroys drones: a background rate, scripted losses and hazard zones."""

    rate_per_s: float = _f(0.0, ge=0.0, le=1000.0)
    """Background loss rate of every live drone, 1/s. A paper per-step probability p maps to
    ``-ln(1 - p) / run.control_period_s`` (:func:`rate_from_per_step`)."""
    scripted: tuple[ScriptedLoss, ...] = ()
    """Losses at given times."""
    hazard_zones: tuple[HazardZone, ...] = ()
    """Regions with an extra loss rate."""

    def per_step(self, control_period_s: float) -> float:
        """Background per-step loss probability at this control period."""
        return per_step_from_rate(self.rate_per_s, control_period_s)


# --------------------------------------------------------------------------------------------
# Endurance: batteries and the base (docs/design/endurance.md)


@dataclass(frozen=True, kw_only=True)
class BatterySpec(_Section):
    """The drones' batteries (truth in the in-process world and the emulator; the station only
    sees what the telemetry says)."""

    endurance_s: float = _f(1500.0, gt=0.0, le=86_400.0)
    """Hover time on a full battery, seconds (25 minutes: a common relay multirotor)."""
    speed_drain_frac: float = _f(0.3, ge=0.0, le=10.0)
    """Extra drain at full speed: the drain is ``(1 + f (v / max_speed)^2) / endurance_s``."""
    low_frac: float = _f(0.20, gt=0.0, lt=1.0)
    """The firmware's low-battery level, as a fraction of capacity, where its failsafe returns
    the drone to launch (what ``--apply-failsafes`` sets; the reference without rotation)."""
    critical_frac: float = _f(0.10, ge=0.0, lt=1.0)
    """The firmware's critical level: its failsafe lands the drone where it is."""

    def validate(self) -> list[tuple[str, str]]:
        if not self.critical_frac < self.low_frac:
            return [("critical_frac", f"must be below low_frac ({_fmt(self.low_frac)})")]
        return []


@dataclass(frozen=True, kw_only=True)
class BaseSpec(_Section):
    """What the base can do for batteries. Unset: the planner's defaults
    (``planner.endurance.BaseResources``, docs/design/endurance.md §2)."""

    pads: int | None = _f(None, ge=1, le=1000)
    """Landing pads where a battery is swapped, one drone at a time each."""
    swap_time_s: float | None = _f(None, gt=0.0, le=86_400.0)
    """Time on the pad for one swap, seconds."""
    spare_batteries: int | None = _f(None, ge=0, le=1_000_000)
    """Charged batteries on the shelf at the start, beyond one in every drone."""
    chargers: int | None = _f(None, ge=0, le=10_000)
    """Batteries charging at once."""
    charge_time_s: float | None = _f(None, gt=0.0, le=86_400.0)
    """Time to charge one battery, seconds."""

    def resources(self) -> Any:
        """The :class:`planner.endurance.BaseResources` of this base (unset fields: defaults)."""
        from planner.endurance import BaseResources

        given = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return BaseResources(**{k: v for k, v in given.items() if v is not None})


@dataclass(frozen=True, kw_only=True)
class EnduranceSpec(_Section):
    """Batteries and relay rotation. Without ``battery`` every battery is endless (the paper's
    world, and every mission that does not ask for endurance)."""

    battery: BatterySpec | None = None
    """The drones' batteries; unset: endless."""
    base: BaseSpec = _f(factory=BaseSpec)
    """Pads, swaps, batteries and chargers at the base."""
    rotation: bool = True
    """Rotate relays through the base before their reserve; false: fly until the firmware's
    low-battery failsafe, relaunch after the swap (the reference)."""
    params: dict[str, float | int] = _f(factory=dict)
    """Rotation policy settings (``planner.endurance.EnduranceParams``: margin_frac, handover_s,
    launch_s, hold_radius_m, slack_s)."""

    def policy(
        self,
        n_drones: int,
        horizon_s: float,
        max_speed_m_s: float,
        mean_post_dist_m: float,
        rotate: bool | None = None,
        flight: dict[str, float] | None = None,
    ) -> Any:
        """The :class:`planner.endurance.RotationPolicy` of this section (the one construction the
        in-process run and the station share; needs ``battery``).

        The level the policy must never reach in the air is the firmware's *first* battery
        action, its low-battery return to launch (``battery.low_frac``): below it the autopilot,
        not the plan, decides. With rotation, ``plan_fleet`` decides how many fly
        (``mean_post_dist_m``: the typical way out to a relay's post); without, all fly.
        ``rotate`` None: this section's ``rotation``. ``flight``: settings the backend knows of
        its vehicles (the station's take-off climb and landing descent,
        :func:`mission.flight.station_loop.rotation_setup`), under the mission's own ``params``."""
        from planner.endurance import EnduranceParams, RotationPolicy, plan_fleet

        assert self.battery is not None  # callers check: no policy for endless batteries
        rotate = self.rotation if rotate is None else rotate
        # The mission's own settings over the backend's (numbers, and refill_lost a flag).
        settings: dict[str, Any] = {**(flight or {}), **self.params}
        params = EnduranceParams(
            critical_frac=self.battery.low_frac, return_speed_m_s=max_speed_m_s, **settings
        )
        base = self.base.resources()
        flying, spare_ratio, turnaround_s = n_drones, 0.0, 0.0
        if rotate:
            plan = plan_fleet(
                n_drones, self.battery.endurance_s, horizon_s, base, params, mean_post_dist_m
            )
            flying, spare_ratio = plan.flying, plan.ground_s / plan.sortie_s
            turnaround_s = plan.ground_s
        return RotationPolicy(
            n_drones,
            flying,
            base,
            params,
            rotate=rotate,
            spare_ratio=spare_ratio,
            turnaround_s=turnaround_s,
        )

    def validate(self) -> list[tuple[str, str]]:
        from planner.endurance import EnduranceParams

        names = {f.name for f in dataclasses.fields(EnduranceParams)}
        names -= {"critical_frac", "return_speed_m_s"}  # from the battery and the vehicles
        bad = sorted(set(self.params) - names)
        if bad:
            return [
                (
                    "params",
                    f"unknown setting(s) {', '.join(bad)}; valid: {', '.join(sorted(names))}",
                )
            ]
        return []


# --------------------------------------------------------------------------------------------
# Planner, run, output


@dataclass(frozen=True, kw_only=True)
class PlannerSpec(_Section):
    """Which planner runs, by name (``planner.methods.METHODS``), with its parameters."""

    method: str = "phireman"
    """Registered planner name, e.g. 'phireman', 'dccrs', 'mccst'."""
    info: InfoMode = "central"
    """The information model every backend of this mission plans with (the ground station of
    ``phireman fly``, the in-process playback, ``phireman sim --mission``): 'central', one planner
    sees every networked drone (the ground station's model, planner.info.STATION_INFO, the
    default); 'async', each drone plans from what reached it by message passing (the paper's,
    docs/design/model.md §5.4). A method with one model (MCCST, 'phireman-central': central only,
    planner.methods.INFO_OF) refuses the other. The paper presets of ``phireman sim`` and the
    sweeps are not missions: they run the planner's own default, the paper's 'async'."""
    params: dict[str, float | int | bool | str] = _f(factory=dict)
    """Method parameters, name -> scalar, in the method's own (paper) units (not ``info``: that is
    ``planner.info``)."""

    def validate(self) -> list[tuple[str, str]]:
        from planner.methods import INFO_OF, METHODS

        if self.method not in METHODS:
            import difflib

            close = difflib.get_close_matches(self.method, list(METHODS), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            return [
                (
                    "method",
                    f"unknown planner method {self.method!r}{hint}; valid methods: "
                    f"{', '.join(METHODS)}",
                )
            ]
        problems = []
        if self.info not in INFO_OF[self.method]:
            problems.append(
                (
                    "info",
                    f"{self.method} plans with {' or '.join(INFO_OF[self.method])} "
                    f"information only, got {self.info!r}",
                )
            )
        if "info" in self.params:
            problems.append(
                ("params", "the information model is planner.info, not a planner parameter")
            )
        return problems

    def run_params(self) -> dict[str, Any]:
        """The parameters to build this planner with (``planner.methods.make_planner``):
        ``params`` plus the information model ``info``. Every backend that runs a mission (the
        station, the in-process playback) calls this: the one place a mission's information model
        is decided (planner.methods.params_with_info)."""
        from planner.methods import params_with_info

        return params_with_info(self.method, self.params, self.info)


@dataclass(frozen=True, kw_only=True)
class RunSpec(_Section):
    """How long and how fast the mission runs."""

    duration_s: float = _f(200.0, gt=0.0, le=7 * 24 * 3600.0)
    """Mission length, seconds (paper: 200 steps)."""
    control_period_s: float = _f(1.0, gt=0.0, le=3600.0)
    """Time between planner ticks, seconds; one paper step."""
    seed: int = _f(0, ge=0, le=2**63 - 1)
    """Seed of every random generator of the run (``np.random.default_rng(seed)`` then spawn)."""
    speedup: float = _f(1.0, gt=0.0, le=10_000.0)
    """Emulated time / wall-clock time for the emulator backend (1 = real time; ignored by the
    in-process simulator, which runs as fast as it can, and by real links)."""

    def validate(self) -> list[tuple[str, str]]:
        if self.duration_s < self.control_period_s:
            return [
                (
                    "duration_s",
                    f"must be at least control_period_s ({_fmt(self.control_period_s)}), "
                    f"got {_fmt(self.duration_s)}",
                )
            ]
        return []

    @property
    def n_steps(self) -> int:
        """Number of control ticks: ``round(duration_s / control_period_s)``."""
        return max(1, round(self.duration_s / self.control_period_s))


@dataclass(frozen=True, kw_only=True)
class GeofenceSpec(_Section):
    """Where drones may fly: a square keep-in box centred on the base station and a ceiling. The
    ground station clips every position target into it."""

    half_width_m: float | None = _f(None, gt=0.0)
    """Half-width of the keep-in square around the base (north and east), metres; unset: the task
    field plus a margin (the runner's default)."""
    max_alt_m: float | None = _f(None, gt=0.0)
    """Ceiling above the base station, metres; unset: no ceiling."""


@dataclass(frozen=True, kw_only=True)
class OutputSpec(_Section):
    """Where runs are recorded."""

    dir: str = "runs"
    """Directory under which each run gets its own sub-directory (relative to the working dir)."""

    def validate(self) -> list[tuple[str, str]]:
        if not self.dir.strip():
            return [("dir", "must not be empty")]
        if "\x00" in self.dir:
            return [("dir", "must not contain NUL characters")]
        return []


# --------------------------------------------------------------------------------------------
# The mission


def _default_vehicles() -> Vehicles:
    return Vehicles(emulated=EmulatedVehicles())


def _default_tasks() -> tuple[Task, ...]:
    return (Task(random=RandomTasks()),)


@dataclass(frozen=True, kw_only=True)
class Mission(_Section):
    """A whole deployment. Every section is optional in YAML; see each class for defaults."""

    name: str = "mission"
    """Short name, used in run directory names."""
    description: str = ""
    """Free text for people."""
    origin: Origin = _f(factory=Origin)
    """Base station location."""
    vehicles: Vehicles = _f(factory=_default_vehicles)
    """The swarm."""
    tasks: tuple[Task, ...] = _f(factory=_default_tasks, min_len=1, max_len=10_000)
    """What must stay networked to the base."""
    radio: Radio = _f(factory=Radio)
    """Radio model."""
    terrain: TerrainSpec | None = None
    """The ground (docs/terrain.md); None: a flat earth. Needed by ``radio.model: terrain``."""
    attrition: Attrition = _f(factory=Attrition)
    """Losses."""
    planner: PlannerSpec = _f(factory=PlannerSpec)
    """Planner choice."""
    run: RunSpec = _f(factory=RunSpec)
    """Duration, control period, seed, speed-up."""
    geofence: GeofenceSpec = _f(factory=GeofenceSpec)
    """Where the ground station lets drones fly."""
    endurance: EnduranceSpec = _f(factory=EnduranceSpec)
    """Batteries, the base's pads and chargers, relay rotation (default: endless batteries)."""
    output: OutputSpec = _f(factory=OutputSpec)
    """Run directory."""

    @property
    def n_tasks(self) -> int:
        """Total number of tasks (generators expanded)."""
        return sum(t.count for t in self.tasks)

    def validate(self) -> list[tuple[str, str]]:
        problems: list[tuple[str, str]] = []
        n = self.vehicles.count
        for i, loss in enumerate(self.attrition.scripted):
            if n and loss.vehicle >= n:
                problems.append(
                    (
                        f"attrition.scripted[{i}].vehicle",
                        f"no vehicle {loss.vehicle}: there are {n} (indices 0..{n - 1})",
                    )
                )
        for i, task in enumerate(self.tasks):
            pts: list[tuple[str, Position]] = []
            if task.track is not None:
                pts = [(f"tasks[{i}].track[{j}]", p) for j, p in enumerate(task.track)]
            elif task.random_walk is not None:
                pts = [(f"tasks[{i}].random_walk.start", task.random_walk.start)]
            for where, p in pts:
                n_m, e_m = (
                    _approx_local_m(self.origin, p.lat_deg, p.lon_deg)  # type: ignore[arg-type]
                    if p.is_geo  # is_geo: lat/lon set
                    else (p.north_m, p.east_m)
                )
                d = math.hypot(n_m, e_m)  # type: ignore[arg-type]  # north/east set unless is_geo
                if d > MAX_DISTANCE_FROM_ORIGIN_M:
                    problems.append(
                        (
                            where,
                            f"is {d / 1000:.0f} km from the origin (limit "
                            f"{MAX_DISTANCE_FROM_ORIGIN_M / 1000:.0f} km); "
                            "swapped lat/lon or wrong origin?",
                        )
                    )
        if self.radio.model == "terrain" and self.terrain is None:
            problems.append(("radio.model", "'terrain' needs a terrain section"))
        if self.n_tasks > 10_000:
            problems.append(("tasks", f"{self.n_tasks} tasks in total; at most 10000"))
        lim, fence = self.vehicles.limits, self.geofence
        top_m = lim.cruise_alt_m + (lim.n_layers - 1) * lim.layer_spacing_m
        if fence.max_alt_m is not None and fence.max_alt_m < top_m:
            problems.append(
                (
                    "geofence.max_alt_m",
                    f"{_fmt(fence.max_alt_m)} m is below the highest "
                    f"cruise layer ({_fmt(top_m)} m)",
                )
            )
        return problems

    def problem_config(self):
        """The :class:`planner.problem.ProblemConfig` this mission implies (for the simulator and
        planners): counts, radii, speed, per-step task sigma and attrition at this control period.

        Spawn positions, tracks, scripted losses and hazard zones are not part of ProblemConfig;
        runners read them from the mission. The paper length unit is ``radio.range_m / 2``.
        """
        from planner.problem import ProblemConfig

        dt = self.run.control_period_s
        fields = [t.random.field_half_width_m for t in self.tasks if t.random is not None]
        fields += [
            t.random_walk.field_half_width_m
            for t in self.tasks
            if t.random_walk is not None and t.random_walk.field_half_width_m is not None
        ]
        unit = paper_length_unit_m(self.radio.range_m)
        sigmas = [t.random.sigma_m_per_sqrt_s for t in self.tasks if t.random is not None]
        sigmas += [
            t.random_walk.sigma_m_per_sqrt_s for t in self.tasks if t.random_walk is not None
        ]
        borders = [t.random.border for t in self.tasks if t.random is not None]
        emu = self.vehicles.emulated
        ring = emu.spawn.ring if emu is not None else None
        return ProblemConfig(
            n_drones=self.vehicles.count,
            n_tasks=self.n_tasks,
            field_half_width_m=max(fields) if fields else 5.0 * unit,
            radio_range_m=self.radio.range_m,
            base_range_m=self.radio.base_range_m,
            max_speed_m_s=self.vehicles.limits.max_speed_m_s,
            ring_radius_m=ring.radius_m if ring is not None else 0.0,
            ring_noise_m=ring.noise_m if ring is not None else 0.0,
            task_walk_sigma_m=(sigmas[0] if sigmas else 0.0) * math.sqrt(dt),
            task_border=borders[0] if borders else "clip",
            attrition_per_step=self.attrition.per_step(dt),
            n_steps=self.run.n_steps,
            dt_s=dt,
            length_unit_m=unit,
            size=self.name,
            reading="mission",
        )

    def summary(self) -> str:
        """One line for people: what this mission flies."""
        v = self.vehicles
        if v.emulated is not None:
            fleet = f"{v.emulated.count} emulated {v.emulated.personality} drones"
        else:
            assert v.real is not None  # exactly one kind is set (validated)
            fleet = f"{len(v.real.connections)} real link(s)"
        kinds: dict[str, int] = {}
        for t in self.tasks:
            kinds[t.kind] = kinds.get(t.kind, 0) + t.count
        tasks = ", ".join(f"{k} {name}" for name, k in kinds.items())
        att = self.attrition
        extra = []
        if att.scripted:
            extra.append(f"{len(att.scripted)} scripted losses")
        if att.hazard_zones:
            extra.append(f"{len(att.hazard_zones)} hazard zones")
        end = self.endurance
        batteries = ""
        if end.battery is not None:
            batteries = f", {end.battery.endurance_s / 60:.0f}-min batteries, " + (
                "relay rotation" if end.rotation else "no rotation"
            )
        return (
            f"{self.name}: {fleet}, {self.n_tasks} tasks ({tasks}), radio {_fmt(self.radio.range_m)} m, "
            f"attrition {att.rate_per_s:.4g}/s"
            + (f" + {', '.join(extra)}" if extra else "")
            + batteries
            + f", planner {self.planner.method} ({self.planner.info}), "
            f"{_fmt(self.run.duration_s)} s at {_fmt(self.run.control_period_s)} s/step, "
            f"seed {self.run.seed}, origin {self.origin.lat_deg:.5f}, {self.origin.lon_deg:.5f}"
        )


# --------------------------------------------------------------------------------------------
# The paper's configurations


def paper_mission(
    size: str = "S",
    attrition_per_step: float = 0.01,
    unit_m: float = 50.0,
    reading: str = "scaled",
    step_s: float = 1.0,
    seed: int = 0,
    origin: Origin | None = None,
) -> Mission:
    """The paper's configuration (Table III, §5.5) as a mission in SI units.

    Parameters
    ----------
    size : {'XS', 'S', 'M', 'L', 'XL'}
    attrition_per_step : float
        Per-drone, per-step loss probability p in [0, 1); becomes ``-ln(1-p)/step_s`` per second.
    unit_m : float
        Metres per paper length unit (> 0).
    reading : {'scaled', 'literal'}
        'scaled' multiplies every length by half-width / 5 (docs/design/model.md §6.4).
    step_s : float
        Seconds per paper step (the control period).
    seed : int
        The run seed.

    Raises
    ------
    ValueError
        Unknown size or reading, or out-of-range numbers.
    """
    from planner.problem import problem_preset

    if not unit_m > 0:
        raise ValueError(f"unit_m must be > 0, got {unit_m}")
    if not step_s > 0:
        raise ValueError(f"step_s must be > 0, got {step_s}")
    cfg = problem_preset(size, attrition_per_step, reading)
    L = unit_m
    return Mission(
        name=f"paper-{cfg.size}-{reading}-p{attrition_per_step * 100:g}pct",
        description=(
            f"RTNUA paper configuration {cfg.size} ({reading} reading), attrition "
            f"{attrition_per_step * 100:g} % per step; 1 paper unit = {_fmt(float(unit_m))} m, "
            f"1 step = {_fmt(float(step_s))} s."
        ),
        origin=origin or Origin(),
        vehicles=Vehicles(
            emulated=EmulatedVehicles(
                count=cfg.n_drones,
                personality="ardupilot",
                spawn=Spawn(
                    ring=SpawnRing(radius_m=cfg.ring_radius_m * L, noise_m=cfg.ring_noise_m * L)
                ),
                max_speed_m_s=cfg.max_speed_m_s * L / step_s,
                radio_range_m=cfg.radio_range_m * L,
            )
        ),
        tasks=(
            Task(
                random=RandomTasks(
                    count=cfg.n_tasks,
                    field_half_width_m=cfg.field_half_width_m * L,
                    sigma_m_per_sqrt_s=cfg.task_walk_sigma_m * L / math.sqrt(step_s),
                    border=cfg.task_border,  # type: ignore[arg-type]  # checked against BORDER_POLICIES
                )
            ),
        ),
        radio=Radio(range_m=cfg.radio_range_m * L, base_range_m=cfg.base_range_m * L),
        attrition=Attrition(rate_per_s=rate_from_per_step(attrition_per_step, step_s)),
        planner=PlannerSpec(method="phireman", info="async"),
        run=RunSpec(duration_s=cfg.n_steps * step_s, control_period_s=step_s, seed=seed),
    )
