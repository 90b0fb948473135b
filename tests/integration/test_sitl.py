"""Real firmware: the shipped SITL missions flown through ``phireman fly`` against ArduCopter SITL
and PX4 SITL (SIH), started by :mod:`mission.flight.sitl` exactly as ``phireman sitl`` starts them.

These need the user's own firmware builds, found through the environment (see mission/flight/sitl.py):
``PHIREMAN_ARDUCOPTER`` (+ ``PHIREMAN_ARDUCOPTER_DEFAULTS``) and ``PHIREMAN_PX4`` (+
``PHIREMAN_PX4_ETC``). Without them each test is skipped with the reason. One flight per firmware
walks the whole life cycle and checks each step from the station's own records (events.jsonl,
metrics.csv, summary.json, flight.tlog):

launch (discover, audit with --apply-failsafes, GUIDED/OFFBOARD, armed, at cruise altitude) ->
plan -> station SIGKILL -> the firmware's own failsafe (RTL / Return) -> a vehicle's firmware
killed while the station is down -> restart with that link gone (retried in the background,
never fatal) -> the others reclaimed -> another vehicle killed in flight -> VehicleLost and the
plan goes on -> end -> landed. Speeds are checked against the mission's limit.

Deadlines are generous (a loaded CI host); nothing asserts on wall-clock durations.
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mission.flight.sitl import SitlSpec, SitlSwarm, find_binary, SitlError

pytestmark = [pytest.mark.sitl, pytest.mark.udp]

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _binary_or_skip(firmware: str) -> Path:
    try:
        return find_binary(firmware)
    except SitlError as exc:
        pytest.skip(f"real-firmware test skipped: {exc}")


def _wait(cond, timeout_s: float, what: str, procs=()):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return
        for p in procs:
            if p.poll() is not None:
                raise AssertionError(f"station exited (rc {p.returncode}) while waiting for {what}")
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")


def _run_dir(parent: Path) -> Path | None:
    dirs = sorted(p for p in parent.glob("*") if p.is_dir()) if parent.exists() else []
    return dirs[-1] if dirs else None


def _events(run_dir: Path | None) -> list[dict]:
    if run_dir is None or not (run_dir / "events.jsonl").exists():
        return []
    out = []
    for line in (run_dir / "events.jsonl").read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass  # the line being written
    return out


def _metrics(run_dir: Path | None) -> list[dict]:
    if run_dir is None or not (run_dir / "metrics.csv").exists():
        return []
    with open(run_dir / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def _tlog_speeds(run_dir: Path) -> dict[int, list[tuple[float, float, float]]]:
    """sysid -> [(unix time, horizontal speed m/s, relative alt m)] from GLOBAL_POSITION_INT."""
    from pymavlink import mavutil

    out: dict[int, list] = {}
    mlog = mavutil.mavlink_connection(str(run_dir / "flight.tlog"), dialect="ardupilotmega")
    while True:
        m = mlog.recv_match(type="GLOBAL_POSITION_INT")
        if m is None:
            break
        v = math.hypot(m.vx, m.vy) / 100.0
        out.setdefault(m.get_srcSystem(), []).append(
            (getattr(m, "_timestamp", 0.0), v, m.relative_alt / 1000.0)
        )
    return out


def _fly(mission: str, connects: list[str], out: Path, *extra: str) -> subprocess.Popen:
    args = [
        *PHIREMAN,
        "fly",
        mission,
        *sum((["--connect", c] for c in connects), []),
        "--apply-failsafes",
        "--out",
        str(out),
        *extra,
    ]
    log = open(out.parent / f"{out.name}.log", "w")
    return subprocess.Popen(
        args,
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )


def _timeline(events: list[dict], t0: float) -> list[str]:
    """Lines 't+  12.3 s  sysid 2  ModeChanged GUIDED' of the notable events."""
    keep = {
        "VehicleDiscovered",
        "ModeChanged",
        "ArmedChanged",
        "VehicleLost",
        "VehicleRecovered",
        "ParamSetConfirmed",
        "LinkDown",
        "LinkUp",
        "StatusText",
    }
    out = []
    for e in events:
        if e.get("type") not in keep:
            continue
        what = (
            e.get("mode")
            or e.get("name")
            or e.get("text")
            or ("armed" if e.get("armed") else "disarmed" if "armed" in e else "")
        )
        out.append(
            f"t+{e.get('t_s', 0) - t0:7.1f} s  sysid {e.get('sysid', '-')}  {e['type']} {what}"
        )
    return out


def _life_cycle(
    tmp_path: Path,
    firmware: str,
    mission: str,
    speedup: float,
    guided_mode: str,
    fs_modes: tuple[str, ...],
) -> None:
    from mission.commands.fly import _load

    binary = _binary_or_skip(firmware)
    m = _load(mission)
    o = m.origin
    spec = SitlSpec(
        firmware,
        3,
        binary,
        (o.lat_deg, o.lon_deg, o.alt_amsl_m),
        speedup=speedup,
        workdir=tmp_path / "sitl",
        first_instance=0,
    )
    speed = ["--speedup", f"{speedup:g}"] if speedup != 1.0 else []
    with SitlSwarm(spec) as sitl:
        conns = sitl.connections()
        # 1. Launch and plan.
        runs1 = tmp_path / "station1"
        st1 = _fly(mission, conns, runs1, "--duration-s", "600", *speed)
        try:
            _wait(
                lambda: len(_metrics(_run_dir(runs1))) >= 5,
                240,
                "the first station to launch all vehicles and plan",
                [st1],
            )
            ev1 = _events(_run_dir(runs1))
            armed = {e["sysid"] for e in ev1 if e["type"] == "ArmedChanged" and e["armed"]}
            guided = {
                e["sysid"] for e in ev1 if e["type"] == "ModeChanged" and e["mode"] == guided_mode
            }
            assert armed == {1, 2, 3} and guided == {1, 2, 3}
            sets = {(e["sysid"], e["name"]) for e in ev1 if e["type"] == "ParamSetConfirmed"}
            print(f"\n[{firmware}] first station: parameters written {sorted(sets)}")
            t1 = ev1[0]["t_s"]
            run_start = float(_metrics(_run_dir(runs1))[0]["t_s"]) - t1
            print(
                f"[{firmware}] first station timeline (plan running, layers reached, at "
                f"t+{run_start:.1f} s):\n  "
                + "\n  ".join(line for line in _timeline(ev1, t1) if "StatusText" not in line)
            )
        finally:
            # 2. The station dies (SIGKILL: no goodbye).
            st1.send_signal(signal.SIGKILL)
            st1.wait(10)
        t_kill = time.monotonic()
        # 3. While it is down, one vehicle's firmware dies too.
        sitl.kill(2)
        # Let the firmware's own link-loss failsafe act (ArduPilot FS_GCS_TIMEOUT 5 s, PX4
        # COM_OF_LOSS_T 1 s + NAV_DLL_ACT after COM_DL_LOSS_T 10 s), on the vehicles' clock.
        time.sleep(12.0 / speedup)
        # 4. Restart with one link gone: never fatal, retried in the background.
        runs2 = tmp_path / "station2"
        st2 = _fly(mission, conns, runs2, "--duration-s", "60", "--vehicles", "2", *speed)
        try:

            def modes_seen():
                ev = _events(_run_dir(runs2))
                return {e["sysid"]: e["mode"] for e in ev if e["type"] == "VehicleDiscovered"}

            _wait(
                lambda: len(modes_seen()) >= 2,
                120,
                "the restarted station to hear 2 vehicles",
                [st2],
            )
            found = modes_seen()
            print(
                f"[{firmware}] restarted station found {found} "
                f"{time.monotonic() - t_kill:.1f} s wall after the SIGKILL"
            )
            assert all(found[s] in fs_modes for s in (1, 2)), found
            # 5. Reclaimed and planned again.
            _wait(
                lambda: len(_metrics(_run_dir(runs2))) >= 5,
                240,
                "the restarted station to reclaim and plan",
                [st2],
            )
            # 6. A vehicle killed in flight: lost, the plan goes on with the other.
            sitl.kill(1)
            _wait(
                lambda: any(
                    e["type"] == "VehicleLost" and e["sysid"] == 2 for e in _events(_run_dir(runs2))
                ),
                60,
                "VehicleLost for sysid 2",
                [st2],
            )
            # 7. The end: the last vehicle lands, the station says so and exits 0.
            rc = st2.wait(600)
        finally:
            if st2.poll() is None:
                st2.send_signal(signal.SIGKILL)
                st2.wait(10)
        run2 = _run_dir(runs2)
        summary = json.loads((run2 / "summary.json").read_text())
        ev2 = _events(run2)
        assert rc == 0, (runs2.parent / "station2.log").read_text()[-3000:]
        assert summary["phase"] == "done"
        # Both survivors flew the plan again: reclaimed in the air, or (PX4 Return is quick near
        # home) relaunched after their own failsafe had landed them.
        back = {e["sysid"] for e in ev2 if e["type"] == "ModeChanged" and e["mode"] == guided_mode}
        assert {1, 2} <= back, back
        assert summary["reclaimed"] >= 1, summary["reclaimed"]
        assert summary["end_status"]["in_air"] == 0, summary["end_status"]
        assert summary["counters"]["lost"] >= 1
        m_rows = _metrics(run2)
        assert int(m_rows[-1]["planned"]) >= 1
        # Speed: never above the mission's limit (+10 % for the controller's overshoot) once
        # the vehicles are under the station's control.
        limit = m.vehicles.limits.max_speed_m_s
        speeds = _tlog_speeds(run2)
        worst = max((v for rows in speeds.values() for _, v, alt in rows if alt > 3.0), default=0.0)
        t0 = ev2[0]["t_s"] if ev2 else 0.0
        print(
            f"[{firmware}] timeline of the restarted station:\n  " + "\n  ".join(_timeline(ev2, t0))
        )
        print(
            f"[{firmware}] TU1/TU2 as the station saw them: {summary['station']['tu1']:.3f} / "
            f"{summary['station']['tu2']:.3f}; max horizontal speed {worst:.2f} m/s "
            f"(mission limit {limit:g})"
        )
        assert worst <= 1.1 * limit, worst


def test_ardupilot_sitl_life_cycle(tmp_path):
    _life_cycle(
        tmp_path,
        "ardupilot",
        "sitl_ardupilot",
        speedup=5.0,
        guided_mode="GUIDED",
        fs_modes=("RTL", "LAND"),
    )


def test_px4_sitl_life_cycle(tmp_path):
    _life_cycle(
        tmp_path,
        "px4",
        "sitl_px4",
        speedup=1.0,
        guided_mode="OFFBOARD",
        fs_modes=("AUTO.RTL", "AUTO.LAND", "AUTO.LOITER"),
    )


# ------------------------------------------------------------------ the audit on real firmware

_REFUSALS = [
    # (firmware, boot parameters, parameter the audit must name, what it must say)
    ("ardupilot", {}, "FS_GCS_ENABLE", "disabled"),  # copter default 0
    ("ardupilot", {"FS_GCS_ENABLE": 5}, "FS_GCS_ENABLE", "Land"),
    # Both spellings: ArduCopter 4.6 has SYSID_MYGCS (ArduCopter/Parameters.cpp), 4.7 renamed it
    # MAV_GCS_SYSID; a defaults file's unknown name is skipped (AP_Param::load_defaults_file),
    # so each version gets the one it knows (with one only, 4.6 booted 255 and the audit
    # rightly cleared the flight).
    (
        "ardupilot",
        {"FS_GCS_ENABLE": 1, "SYSID_MYGCS": 200, "MAV_GCS_SYSID": 200},
        "SYSID",
        "does not include",
    ),
    ("px4", {"NAV_DLL_ACT": 0}, "NAV_DLL_ACT", "disabled"),  # PX4 default
    ("px4", {"NAV_DLL_ACT": 2, "COM_OBL_RC_ACT": 0, "NAV_RCL_ACT": 6}, "NAV_RCL_ACT", "isarm"),
    ("px4", {"NAV_DLL_ACT": 2, "COM_OBL_RC_ACT": 4}, "COM_OBL_RC_ACT", "Land"),
]


@pytest.mark.parametrize(
    "firmware,params,name,words",
    _REFUSALS,
    ids=[
        f"{f}-{n}-{'-'.join(f'{k}{v}' for k, v in p.items()) or 'defaults'}"
        for f, p, n, _ in _REFUSALS
    ],
)
def test_the_audit_refuses_unsafe_lost_link_settings_on_real_firmware(
    tmp_path, firmware, params, name, words
):
    """Each unsafe setting, booted into the real firmware, makes `phireman fly` (without
    --apply-failsafes) refuse before anything is armed, naming the parameter."""
    binary = _binary_or_skip(firmware)
    from mission.flight.sitl import DEFAULT_HOMES

    mission = "sitl_ardupilot" if firmware == "ardupilot" else "sitl_px4"
    spec = SitlSpec(
        firmware,
        1,
        binary,
        DEFAULT_HOMES[firmware],
        params=dict(params),
        workdir=tmp_path / "sitl",
        first_instance=0,
    )
    with SitlSwarm(spec) as sitl:
        out = subprocess.run(
            [
                *PHIREMAN,
                "fly",
                mission,
                "--connect",
                sitl.connection(0),
                "--out",
                str(tmp_path / "runs"),
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    text = out.stdout + out.stderr
    assert out.returncode == 1, text[-3000:]
    assert "refused the flight" in text
    blocking = [line for line in text.splitlines() if "[blocking]" in line]
    assert any(name in line and words in line for line in blocking), text[-3000:]
    assert "ArmedChanged" not in (next((tmp_path / "runs").iterdir()) / "events.jsonl").read_text()
