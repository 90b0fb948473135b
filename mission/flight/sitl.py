"""A swarm of real-firmware SITL instances around a mission's origin (``phireman sitl``).

This starts firmware the *user* built (ArduCopter SITL, or PX4 SITL with the SIH physics that
runs inside the ``px4`` binary); phireman ships no firmware and no recipe to build it. It does
for our missions what ArduPilot's ``sim_vehicle.py --count`` / ``--auto-sysid`` and PX4's
multi-vehicle SIH scripts do: one process per vehicle, each in its own working directory, with
distinct system ids and ports, homes spread around the mission origin, and it stops exactly the
processes it started (each in its own process group).

Where the binaries are: ``--binary`` or the environment (tests use the same variables):

* ``PHIREMAN_ARDUCOPTER`` - the ``arducopter`` SITL binary (``build/sitl/bin/arducopter``);
  ``PHIREMAN_ARDUCOPTER_DEFAULTS`` - its defaults file, by default ``copter.parm`` beside the
  binary (ArduPilot ``Tools/autotest/default_params/copter.parm``).
* ``PHIREMAN_PX4`` - the ``px4`` binary of a ``px4_sitl`` build (``build/px4_sitl_default/
  bin/px4``); ``PHIREMAN_PX4_ETC`` - its ROMFS ``etc`` directory, by default ``../etc`` from
  the binary's directory.

Facts of the firmware this follows (checked on ArduCopter 4.7-dev and PX4 main):

* ArduCopter SITL instance ``i`` (``-I i``) serves MAVLink SERIAL0 on TCP ``5760 + 10 i``, one
  client at a time (libraries/AP_HAL_SITL/SITL_cmdline.cpp, ``_base_port + 10 * instance``);
  ``--sysid`` sets its MAVLink system id, ``--home LAT,LON,ALT,HDG`` its home, ``--speedup K``
  runs its clock K times faster (the station must then run ``--speedup K`` too), ``-w`` wipes
  the eeprom to the defaults (copter defaults have FS_GCS_ENABLE = 0: the audit refuses them
  until ``--apply-failsafes``).
* PX4 SITL instance ``i`` (``px4 -i i``) has MAV_SYS_ID ``i + 1`` and its GCS MAVLink link on
  local UDP ``18570 + i`` (ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink), sending to UDP
  14550 until it latches onto the first ground station it hears, for good: the station listens
  with ``udpin:127.0.0.1:14550`` (one link for every instance, the port a restarted station
  binds again).
  SIH's home comes from SIH_LOC_LAT0 / SIH_LOC_LON0 / SIH_LOC_H0, and any parameter can be given
  at boot as ``PX4_PARAM_<NAME>=<value>`` in the environment (init.d-posix/rcS). PX4 keeps
  ``/tmp/px4-sock-<i>`` and ``/tmp/px4_lock-<i>`` per instance, so instance numbers must be
  unique on the machine (``first_instance``).
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "SitlError",
    "SitlSpec",
    "SitlSwarm",
    "FIRMWARES",
    "find_binary",
    "home_positions",
    "DEFAULT_HOMES",
]

log = logging.getLogger(__name__)

FIRMWARES = ("ardupilot", "px4")

#: Each firmware's own default SITL home (lat, lon, alt AMSL m): ArduPilot's CMAC
#: (Tools/autotest/locations.txt), PX4 SIH's SIH_LOC_LAT0/LON0/H0 (Zurich).
DEFAULT_HOMES = {"ardupilot": (-35.363261, 149.165230, 584.0), "px4": (47.397742, 8.545594, 489.4)}

_ENV = {"ardupilot": "PHIREMAN_ARDUCOPTER", "px4": "PHIREMAN_PX4"}

#: Where every PX4 SITL instance sends its GCS link (px4-rc.mavlink: the mavlink module's
#: default remote port).
PX4_GCS_PORT = 14550
_EARTH_RADIUS_M = 6_371_008.8


class SitlError(RuntimeError):
    """Something the user can fix (no binary, a port in use): one line, no traceback."""


def find_binary(firmware: str, binary: str | None = None) -> Path:
    """The firmware binary: ``binary`` if given, else the environment variable; SitlError with
    what to set when neither is usable."""
    if firmware not in FIRMWARES:
        raise SitlError(f"unknown firmware {firmware!r}; valid: {', '.join(FIRMWARES)}")
    text = binary or os.environ.get(_ENV[firmware])
    if not text:
        what = (
            "your ArduCopter SITL binary (build/sitl/bin/arducopter in an ArduPilot tree, "
            "see ArduPilot's SITL documentation)"
            if firmware == "ardupilot"
            else "your PX4 SITL binary (build/px4_sitl_default/bin/px4 in a PX4-Autopilot tree, "
            "see PX4's simulation documentation)"
        )
        raise SitlError(
            f"no {firmware} SITL binary: pass --binary PATH or set {_ENV[firmware]} to {what}"
        )
    path = Path(text).expanduser()
    if not path.is_file() or not os.access(path, os.X_OK):
        raise SitlError(f"{firmware} SITL binary {str(path)!r} is not an executable file")
    return path.resolve()


def home_positions(
    n: int, origin: tuple[float, float, float], spacing_m: float = 5.0
) -> list[tuple[float, float, float]]:
    """Homes of ``n`` vehicles on a row through ``origin``, west to east, ``spacing_m`` apart
    (lat, lon, alt AMSL): close enough for one base station, far enough not to collide."""
    lat0, lon0, alt0 = origin
    out = []
    for i in range(n):
        east = (i - (n - 1) / 2.0) * spacing_m
        dlon = math.degrees(east / (_EARTH_RADIUS_M * math.cos(math.radians(lat0))))
        out.append((lat0, lon0 + dlon, alt0))
    return out


@dataclass
class SitlSpec:
    """What to start."""

    firmware: str
    n_vehicles: int
    binary: Path
    origin: tuple[float, float, float]
    speedup: float = 1.0
    """ArduCopter ``--speedup``; PX4 SIH runs at 1x (its lock-step clock)."""
    workdir: Path | None = None
    """Parent of the per-instance working directories (default: a new temporary directory,
    removed by :meth:`SitlSwarm.stop`)."""
    first_instance: int = 0
    spacing_m: float = 5.0
    defaults: Path | None = None
    """ArduCopter defaults file (default ``$PHIREMAN_ARDUCOPTER_DEFAULTS`` or copter.parm
    beside the binary)."""
    px4_etc: Path | None = None
    params: dict[str, float] = field(default_factory=dict)
    """PX4: boot parameters (``PX4_PARAM_<NAME>``); ArduPilot: written to an extra defaults
    file loaded after the firmware's own."""

    def __post_init__(self) -> None:
        if self.firmware not in FIRMWARES:
            raise SitlError(f"unknown firmware {self.firmware!r}; valid: {', '.join(FIRMWARES)}")
        if not 1 <= self.n_vehicles <= 64:
            raise SitlError(f"--vehicles must be in 1..64, got {self.n_vehicles}")
        if not self.speedup > 0:
            raise SitlError(f"--speedup must be > 0, got {self.speedup}")
        if self.firmware == "px4" and self.speedup != 1.0:
            raise SitlError("PX4 SIH runs at 1x here (its lock-step clock); drop --speedup")


class SitlSwarm:
    """The started instances; :meth:`connections` are the station's ``--connect`` strings."""

    def __init__(self, spec: SitlSpec) -> None:
        self.spec = spec
        self.procs: list[subprocess.Popen] = []
        self.homes = home_positions(spec.n_vehicles, spec.origin, spec.spacing_m)
        self._tmp: str | None = None
        self.workdir: Path | None = None

    # ------------------------------------------------------------------ who is where

    def instance(self, k: int) -> int:
        return self.spec.first_instance + k

    def sysid(self, k: int) -> int:
        return self.instance(k) + 1

    def connection(self, k: int) -> str:
        """The station's link to vehicle ``k``. PX4: every instance sends its GCS link to UDP
        14550 and latches onto the first ground station it hears for good
        (src/modules/mavlink/mavlink_receiver.cpp, ``set_client_source_initialized``): a station
        restarted on another port would never be answered, so all share ``udpin`` 14550, the
        port a restarted station binds again."""
        i = self.instance(k)
        if self.spec.firmware == "ardupilot":
            return f"tcp:127.0.0.1:{5760 + 10 * i}"
        return f"udpin:127.0.0.1:{PX4_GCS_PORT}"

    def connections(self) -> list[str]:
        """The distinct links that reach every vehicle (ArduPilot: one each; PX4: one)."""
        return list(dict.fromkeys(self.connection(k) for k in range(self.spec.n_vehicles)))

    # ------------------------------------------------------------------ start / stop

    def start(self) -> SitlSwarm:
        spec = self.spec
        if spec.workdir is None:
            self._tmp = tempfile.mkdtemp(prefix=f"phireman-sitl-{spec.firmware}-")
            self.workdir = Path(self._tmp)
        else:
            self.workdir = Path(spec.workdir)
            self.workdir.mkdir(parents=True, exist_ok=True)
        try:
            for k in range(spec.n_vehicles):
                self.procs.append(self._start_one(k))
        except BaseException:
            self.stop()
            raise
        return self

    def _start_one(self, k: int, wipe: bool = True) -> subprocess.Popen:
        """Start vehicle ``k``. ``wipe`` False: boot on what the instance stored in its working
        directory (ArduPilot's eeprom; PX4's parameter file), as a power cycle does."""
        spec, i = self.spec, self.instance(k)
        assert self.workdir is not None  # set by start()
        cwd = self.workdir / f"{spec.firmware}-{i}"
        cwd.mkdir(parents=True, exist_ok=True)
        lat, lon, alt = self.homes[k]
        env = dict(os.environ)
        if spec.firmware == "ardupilot":
            defaults = spec.defaults or (
                Path(os.environ["PHIREMAN_ARDUCOPTER_DEFAULTS"])
                if os.environ.get("PHIREMAN_ARDUCOPTER_DEFAULTS")
                else spec.binary.parent / "copter.parm"
            )
            files = [str(defaults)] if defaults.is_file() else []
            if spec.params:
                extra = cwd / "phireman.parm"
                extra.write_text("".join(f"{n} {v:g}\n" for n, v in spec.params.items()))
                files.append(str(extra))
            cmd = [
                str(spec.binary),
                "--model",
                "quad",
                "--speedup",
                f"{spec.speedup:g}",
                "-I",
                str(i),
                "--sysid",
                str(i + 1),
                "--home",
                f"{lat:.7f},{lon:.7f},{alt:.2f},0",
                *(["-w"] if wipe else []),
                # Without it SERIAL0 is "tcp:0:wait": the firmware would not boot (GPS,
                # EKF) until a ground station connects (libraries/AP_HAL_SITL/SITL_cmdline.cpp).
                "--serial0",
                "tcp:0",
            ]
            if files:
                cmd += ["--defaults", ",".join(files)]
        else:
            etc = spec.px4_etc or (
                Path(os.environ["PHIREMAN_PX4_ETC"])
                if os.environ.get("PHIREMAN_PX4_ETC")
                else spec.binary.parent.parent / "etc"
            )
            if not etc.is_dir():
                raise SitlError(
                    f"PX4 ROMFS etc directory {str(etc)!r} not found: set "
                    "PHIREMAN_PX4_ETC to build/px4_sitl_default/etc"
                )
            for stale in (f"/tmp/px4-sock-{i}", f"/tmp/px4_lock-{i}"):
                _remove_if_stale(stale)
            env.update(
                PX4_SIM_MODEL="sihsim_quadx", PX4_SIMULATOR="sihsim", PX4_SYS_AUTOSTART="10040"
            )
            boot = {"SIH_LOC_LAT0": lat, "SIH_LOC_LON0": lon, "SIH_LOC_H0": alt, **spec.params}
            for name, value in boot.items():
                env[f"PX4_PARAM_{name}"] = (
                    f"{value:.7f}" if isinstance(value, float) else str(value)
                )
            cmd = [str(spec.binary), "-i", str(i), "-d", str(etc)]
        log_path = cwd / "console.log"
        with open(log_path, "ab") as out:
            proc = subprocess.Popen(
                cmd,
                cwd=cwd,
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        log.info("started %s instance %d (pid %d): %s", spec.firmware, i, proc.pid, " ".join(cmd))
        return proc

    def alive(self) -> list[bool]:
        return [p.poll() is None for p in self.procs]

    def kill(self, k: int, sig: int = signal.SIGKILL) -> None:
        """Kill vehicle ``k`` (its whole process group): a vehicle lost in flight."""
        _kill_group(self.procs[k], sig)

    def power_cycle(self, k: int, timeout_s: float = 10.0) -> None:
        """Vehicle ``k``'s battery swap: its power cut (SIGKILL to its process group, no
        goodbye), then the same instance booted again in the same working directory with the
        same system id, home and ports. What it stored survives, as on an autopilot whose pack is
        changed: ArduPilot SITL is started without ``-w`` and reads its ``eeprom.bin``
        (libraries/AP_HAL_SITL/SITL_cmdline.cpp, ``-w`` wipes it); PX4 reloads its parameter file
        (ROMFS/px4fmu_common/init.d-posix/rcS: ``param import`` of ``parameters.bson``). The simulated battery starts full:
        ArduPilot's monitor counts the used mAh from zero at boot, PX4's battery simulator is full
        while disarmed (src/modules/simulation/battery_simulator/BatterySimulator.cpp, ``Run``)."""
        proc = self.procs[k]
        _kill_group(proc, signal.SIGKILL)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired as exc:
            raise SitlError(
                f"{self.spec.firmware} instance {self.instance(k)} did not die"
            ) from exc
        if self.spec.firmware == "px4":
            i = self.instance(k)
            for stale in (f"/tmp/px4-sock-{i}", f"/tmp/px4_lock-{i}"):
                _remove_if_stale(stale)
        self.procs[k] = self._start_one(k, wipe=False)
        log.info("power-cycled %s instance %d", self.spec.firmware, self.instance(k))

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop every process this swarm started (SIGTERM, then SIGKILL), nothing else."""
        for p in self.procs:
            _kill_group(p, signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for p in self.procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                _kill_group(p, signal.SIGKILL)
                p.wait(5.0)
        if self.spec.firmware == "px4":
            for k in range(len(self.procs)):
                i = self.instance(k)
                for stale in (f"/tmp/px4-sock-{i}", f"/tmp/px4_lock-{i}"):
                    _remove_if_stale(stale)
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> SitlSwarm:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _kill_group(proc: subprocess.Popen, sig: int) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, sig)  # start_new_session: the group is the instance's own
    except ProcessLookupError:
        pass


def _remove_if_stale(path: str) -> None:
    """PX4's per-instance socket and lock files: removed only if no process holds them."""
    p = Path(path)
    if not p.exists():
        return
    try:
        out = subprocess.run(["fuser", str(p)], capture_output=True, text=True, timeout=5)
        if out.stdout.strip():
            raise SitlError(
                f"{path} is in use: another PX4 SITL instance with this number is "
                "running (stop it, or choose --first-instance)"
            )
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        p.unlink()
    except OSError:
        pass
