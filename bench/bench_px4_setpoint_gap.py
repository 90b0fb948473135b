"""Worst setpoint gap to each PX4 vehicle over a real-firmware flight with the host under load.

PX4 leaves OFFBOARD (its offboard-loss failsafe) when no setpoint arrived for COM_OF_LOSS_T
(1 s by default, src/modules/commander/HealthAndArmingChecks/checks/offboardCheck.cpp): the
station's setpoint stream must stay well under that whatever else the host does. This flies the
shipped ``sitl_px4`` mission with N PX4 SIH vehicles (your own build, ``PHIREMAN_PX4``; see
mission/flight/sitl.py) while ``--load`` busy processes compete for the CPU, then reports per vehicle:

* from the station's own .tlog: the largest interval between two SET_POSITION_TARGET_GLOBAL_INT
  frames sent to the vehicle while it flew the plan;
* from PX4's own log (the .ulg each instance writes; needs ``pip install pyulog``): the largest
  interval between two ``offboard_control_mode`` messages, i.e. as the firmware received them.

    python bench/bench_px4_setpoint_gap.py --vehicles 3 --duration-s 300 --load 2
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _station_gaps(run_dir: Path) -> dict[int, dict]:
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(run_dir / "flight.tlog"), dialect="ardupilotmega")
    times: dict[int, list[float]] = {}
    while True:
        m = mlog.recv_match(type="SET_POSITION_TARGET_GLOBAL_INT")
        if m is None:
            break
        if m.get_srcSystem() == 255:
            times.setdefault(m.target_system, []).append(m._timestamp)
    out = {}
    for sysid, t in sorted(times.items()):
        gaps = [b - a for a, b in zip(t, t[1:])]
        gaps.sort()
        out[sysid] = {
            "setpoints": len(t),
            "max_gap_s": gaps[-1] if gaps else math.nan,
            "p99_gap_s": gaps[int(0.99 * (len(gaps) - 1))] if gaps else math.nan,
        }
    return out


def _px4_gaps(workdir: Path) -> dict[str, dict]:
    try:
        from pyulog import ULog
    except ImportError:
        return {"error": "pyulog not installed (pip install pyulog): no firmware-side figure"}
    out = {}
    for ulg in sorted(workdir.glob("px4-*/**/*.ulg")):
        try:
            log = ULog(str(ulg), ["offboard_control_mode"])
        except Exception as exc:  # noqa: BLE001 - a log cut by the kill at the end
            out[str(ulg)] = {"error": str(exc)}
            continue
        ts = []
        for d in log.data_list:
            ts.extend((d.data["timestamp"] * 1e-6).tolist())
        ts.sort()
        gaps = sorted(b - a for a, b in zip(ts, ts[1:]) if b > a)
        instance = ulg.relative_to(workdir).parts[0]
        out[instance] = {"messages": len(ts), "max_gap_s": gaps[-1] if gaps else math.nan}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--duration-s", type=float, default=300.0)
    ap.add_argument("--load", type=int, default=2, help="busy processes competing for the CPU")
    ap.add_argument("--keep", default=None, help="keep the SITL working directories here")
    args = ap.parse_args()

    from mission.commands.fly import _load
    from mission.flight.sitl import SitlSpec, SitlSwarm, find_binary

    m = _load("sitl_px4")
    o = m.origin
    workdir = Path(args.keep or tempfile.mkdtemp(prefix="bench-px4-gap-"))
    spec = SitlSpec(
        "px4",
        args.vehicles,
        find_binary("px4"),
        (o.lat_deg, o.lon_deg, o.alt_amsl_m),
        workdir=workdir / "sitl",
    )
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.load)]
    try:
        with SitlSwarm(spec) as sitl:
            out = workdir / "runs"
            cmd = [
                str(Path(sys.executable).with_name("phireman")),
                "fly",
                "sitl_px4",
                *sum((["--connect", c] for c in sitl.connections()), []),
                "--apply-failsafes",
                "--duration-s",
                f"{args.duration_s:g}",
                "--out",
                str(out),
            ]
            print("running:", " ".join(cmd), flush=True)
            t0 = time.monotonic()
            rc = subprocess.run(cmd, cwd=ROOT).returncode
            print(f"phireman fly exited {rc} after {time.monotonic() - t0:.0f} s", flush=True)
    finally:
        for p in busy:
            p.kill()
    run_dir = next(out.iterdir())
    summary = json.loads((run_dir / "summary.json").read_text())
    station = _station_gaps(run_dir)
    px4 = _px4_gaps(workdir / "sitl")
    print(
        f"\n{args.vehicles} PX4 SIH vehicles, {args.duration_s:g} s mission, {args.load} busy "
        f"processes; station TU1/TU2 {summary['station']['tu1']:.3f} / "
        f"{summary['station']['tu2']:.3f}"
    )
    print("station's .tlog (setpoints sent):")
    for sysid, g in station.items():
        print(
            f"  sysid {sysid}: {g['setpoints']} setpoints, max gap {g['max_gap_s']:.3f} s, "
            f"p99 {g['p99_gap_s']:.3f} s"
        )
    print("PX4's own log (offboard_control_mode received):")
    for inst, g in px4.items():
        print(f"  {inst}: {g}")
    failsafes = [
        e
        for e in map(json.loads, (run_dir / "events.jsonl").read_text().splitlines())
        if e.get("type") == "StatusText" and "failsafe" in e.get("text", "").lower()
    ]
    print(f"failsafe texts from the vehicles during the flight: {len(failsafes)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
