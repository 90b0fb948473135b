"""Issue 16.4: the station's decisions and the emulator's flight unchanged, bit for bit.

Flies three in-memory lock-step missions (``mission.flight.ether.LockstepEther``, virtual clock, the
helper of ``tests/integration/test_pair.py``) with this tree and with a previous one
(``--commit REV``: a ``git archive`` into a temp dir, or ``--baseline DIR``), and compares a
digest of every tick record, every link event, the vehicles' final positions, the emulator's
per-core counters and the operator's reclaims and counters: a relay loss with reclaims
(ArduPilot), scripted kills with 5 % datagram loss (ArduPilot), PX4 with 2 % loss.

    .venv/bin/python bench/bench_loop_identity.py --commit 64a57d8

Exit status 1 if any digest differs. (The asyncio adapters are not in this path: the in-memory
ether calls the cores directly.)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

CHILD = r"""
import hashlib, json, sys
sys.path.insert(0, "tests/integration"); sys.path.insert(0, "tests")
import numpy as np
from test_pair import _InMemoryFlight, _mission, Task, TrackPoint
far = (Task(track=(TrackPoint(t_s=0.0, north_m=180.0, east_m=0.0),)),)
out = {}
for name, mission, kill_relays, loss in (
    ("relay_loss_ardupilot", _mission(n=4, duration_s=200.0, tasks=far), True, 0.0),
    ("kills_loss5_ardupilot", _mission(n=12, duration_s=120.0, kills=((20.0, 3), (40.0, 7))), False, 0.05),
    ("loss2_px4", _mission(n=8, personality="px4", duration_s=80.0), False, 0.02),
):
    f = _InMemoryFlight(mission, loss=loss)
    f.run_until_phase("run")
    t0 = f.op.mission_t0_s
    f.run_until(t0 + 60.0)
    if kill_relays:
        dist = np.linalg.norm(f.swarm.physics.pos_ned_m[:, :2], axis=1)
        for i in [i for i in np.argsort(dist) if dist[i] <= 100.0]:
            f.swarm.kill(int(i), f.ether.now_s, "test")
    f.run_until(t0 + mission.run.duration_s)
    h = hashlib.sha256()
    h.update(json.dumps([r.row() for r in f.op.records], default=str).encode())
    h.update(json.dumps([repr(e) for e in f.events]).encode())
    h.update(f.swarm.physics.pos_ned_m.tobytes())
    h.update(json.dumps(f.swarm.core_stats(), sort_keys=True).encode())
    h.update(json.dumps([f.op.reclaimed, dict(f.op.counters)], default=str).encode())
    out[name] = [len(f.op.records), len(f.events), h.hexdigest()[:16]]
print(json.dumps(out))
"""


def run_tree(tree: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", CHILD],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": tree},
        cwd=tree,
    )
    if out.returncode:
        sys.exit(f"{tree}: {out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--baseline", help="root of the previous code tree")
    src.add_argument("--commit", help="git archive this revision as the baseline")
    args = ap.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    tmp = None
    base = args.baseline
    if base is None:
        tmp = tempfile.mkdtemp(prefix="bench_loop_identity_")
        subprocess.run(
            f"git -C {here} archive {args.commit} | tar -x -C {tmp}", shell=True, check=True
        )
        base = tmp
    try:
        old, new = run_tree(base), run_tree(here)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    same = old == new
    print(json.dumps({"old": old, "new": new, "identical": same}, indent=1))
    sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
