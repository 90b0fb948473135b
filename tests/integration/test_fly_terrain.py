"""`phireman fly` of a terrain mission over loopback UDP (docs/terrain.md §6): the emulator's radio
and ground over the deep canyon, the station's altitudes over the DEM, ArduPilot's terrain protocol
between the emulated vehicles and the station (port 0 only)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mission.format.examples import example_path

pytestmark = pytest.mark.udp

ROOT = Path(__file__).resolve().parents[2]
PHIREMAN = [str(Path(sys.executable).with_name("phireman"))]


def _small_canyon(tmp_path: Path) -> Path:
    # The deep canyon: its 60 m ridge is above PX4's default return altitude too (60 m), so the
    # audit raises the return altitude on both firmwares (on `canyon`, a 20 m ridge, PX4's
    # default already clears it).
    text = example_path("canyon_deep").read_text()
    text = re.sub(r"count: 40", "count: 8", text)
    text = re.sub(r"duration_s: 300\.0", "duration_s: 60.0", text)
    path = tmp_path / "canyon_deep8.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("personality", ["ardupilot", "px4"])
def test_fly_canyon_keeps_clear_of_the_ground_and_serves_terrain(tmp_path, personality):
    out = subprocess.run(
        [
            *PHIREMAN,
            "fly",
            str(_small_canyon(tmp_path)),
            "--personality",
            personality,
            "--apply-failsafes",  # the return altitude over the ridge (gcs/audit.py)
            "--out",
            str(tmp_path / "runs"),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    run = next((tmp_path / "runs").iterdir())
    s = json.loads((run / "summary.json").read_text())
    assert s["phase"] == "done"
    emu = s["emulator"]
    assert emu["terrain_crashes"] == 0
    # flying the station's targets, never closer to the ground than the mission's clearance
    assert emu["least_agl_m"] is not None and emu["least_agl_m"] >= 15.0 - 1.0
    assert s["truth"]["tu1"] > 0.3
    # the station counts a crew covered by the same line-of-sight model over its map
    assert abs(s["station"]["tu1"] - s["truth"]["tu1"]) < 0.1
    assert "over the terrain: 0 crashes into the ground" in out.stdout
    # the firmware's own return raised over the ridge: 60 m over the rims, plus the clearance
    rtl = "RTL_ALT 1500 -> 7500" if personality == "ardupilot" else "RTL_RETURN_ALT 60 -> 75"
    # every vehicle heard on its pad and audited (vehicle_emu/terrain.py VEHICLE_ANTENNA_AGL_M);
    # one discovered after the fleet audit is audited on its own before it may fly
    # (gcs/operations/late_audit.py): read, fixed and confirmed on all 8 either way
    assert (out.stdout + out.stderr).count(f"{rtl} (confirmed)") == 8, out.stderr[-3000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    name = rtl.split()[0]
    read = {e["sysid"] for e in events if e["type"] == "ParamReceived" and e["name"] == name}
    assert read == set(range(1, 9))
    assert s["audit"]["cleared_to_fly"]
    assert all(late["verdict"] == "cleared" for late in s["audit"]["late"]), s["audit"]
    if personality == "ardupilot":
        t = s["terrain"]
        assert t["requests_answered"] > 0 and t["terrain_data_sent"] >= 56
        assert t["reports"] and all(r["spacing_m"] == 10 for r in t["reports"] if r["loaded"])
        assert sum(r["pending"] == 0 and r["loaded"] > 0 for r in t["reports"]) >= 6
    else:
        assert "terrain" not in s or not s["terrain"]["reports"]  # PX4 has no terrain protocol
