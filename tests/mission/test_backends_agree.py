"""The in-process backend and the emulated backend agree on a short mission (issue 13 point 3).

Same mission, same seed, both backends, ground truth on both sides:

* in-process: :func:`mission.experiments.playback.run_inprocess` - the world model stepped by
  :func:`mission.experiments.world_loop.run_world`, targets from the station's tick (:func:`gcs.control.tick`);
* emulated: the station's operator (:func:`mission.flight.station_loop.make_operator`) flying emulated
  ArduPilot and PX4 vehicles (``personality: mixed``) through the in-memory MAVLink ether
  (:class:`mission.flight.ether.LockstepEther`, virtual clock, no sockets), with the mission's world
  rules (:class:`mission.flight.mission_world.MissionWorld`); truth sampled on the mission's step grid.

Both start from the same spawn, see the same task tracks and random walk and plan with the same
planner on the same algorithm stream. What still differs is the vehicle, not the mission: the
station sees telemetry (2-4 Hz) instead of the truth, the autopilot's position loop (first order,
tau 1 s, led by ``ControlConfig.lead``) replaces the world's exact one-step move, and the radio's
D'(t) is sampled every 0.2 s. That moves a task's first connection by about one step, and it
can, rarely, tip the planner's late configuration into a different local optimum.

Tolerances (measured on seeds 0-7 of this mission with ``mixed``, ``ardupilot`` and ``px4``:
per-seed |dTU1| is at most 0.01 on seeds 0-6 and 0.10 on seed 7, whose late configuration tips
(|dTU2| 0.09); the step series agree on >= 95 % of the steps on seeds 0-6, 70 % on seed 7; the
test flies seeds 0-3 to stay fast):

* every seed: the first connection instants agree (the transient), |dTU1|, |dTU2| <= 0.12;
* the mean over the seeds: |dTU1|, |dTU2| <= 0.04, connected-task counts equal on >= 85 % of
  the steps.

Each of these mutations, tried by hand, fails at least one test: the in-process backend drawing
another seed's scenario (spawn), flying in a swapped frame (north <-> east tasks), ignoring the
planner, or moving ``ControlConfig.lead`` times its planned step; the emulator's mission clock
started one or two steps late.
"""

from __future__ import annotations

import numpy as np
import pytest

from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.format.load import loads_mission
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.experiments.playback import run_inprocess
from mission.flight.station_loop import make_operator

DURATION_S = 40.0
SEEDS = (0, 1, 2, 3)

MISSION = f"""
name: backends-agree
vehicles:
  emulated:
    count: 9
    personality: mixed
    max_speed_m_s: 5.0
    spawn: {{ring: {{radius_m: 10.0, noise_m: 2.0}}}}
radio: {{range_m: 60.0, base_range_m: 60.0}}
tasks:
  - name: north
    track: [{{t_s: 0, north_m: 85, east_m: 30}}, {{t_s: 40, north_m: 95, east_m: 60}}]
  - name: west
    track: [{{t_s: 0, north_m: -40, east_m: -80}}, {{t_s: 40, north_m: -70, east_m: -75}}]
  - name: walk
    random_walk: {{start: {{north_m: 20, east_m: 60}}, sigma_m_per_sqrt_s: 1.0}}
planner: {{method: phireman, info: central}}
run: {{duration_s: {DURATION_S}, control_period_s: 1.0, seed: SEED}}
"""


def _mission(seed: int):
    return loads_mission(MISSION.replace("SEED", str(seed)))


def _fly_in_memory(mission, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fly ``mission`` with the station against the emulator in memory; the truth's (K, M)
    task connection on the mission's step grid ``t0 + k * dt``, k = 0 .. K-1, and the (N, 2)
    true positions (north, east) at t0."""
    scenario = mission_scenario(mission, seed)
    swarm = build_swarm(mission, scenario, seed=seed)
    world = MissionWorld(mission, scenario, swarm)
    station = station_for_swarm(swarm)
    op = make_operator(
        mission, scenario, station, FlyOptions(wave_size=10), mission.vehicles.count, 0.0, seed
    )
    ether = LockstepEther(swarm, station, np.random.default_rng(seed))
    ether.on_event = op.handle_event

    def poll(now_s: float) -> None:
        op.poll(now_s)
        if world.t0_s is None and op.mission_t0_s is not None:
            world.start(op.mission_t0_s)
        world.poll(now_s)

    while (
        world.t0_s is None or ether.now_s < world.t0_s + DURATION_S + 1.0
    ) and ether.now_s < 300.0:
        ether.advance_to(ether.now_s + 1.0, poll=poll, poll_period_s=0.5)
    assert world.t0_s is not None, f"the mission never started (phase {op.phase})"
    t = np.asarray(swarm.truth.t_s) - world.t0_s
    in_mission = (t > -1e-9) & (t < DURATION_S - 1e-9)
    assert np.allclose(np.diff(t[in_mission]), mission.run.control_period_s)
    start_ne_m = np.asarray(swarm.truth.pos_ned_m)[in_mission][0][:, :2]
    return np.asarray(swarm.truth.task_connected)[in_mission], start_ne_m


def _tu(connected: np.ndarray) -> tuple[float, float]:
    from planner.metrics import uptime_series

    s = uptime_series(connected)
    return s.tu1, s.tu2


@pytest.fixture(scope="module")
def runs():
    out = {}
    for seed in SEEDS:
        mission = _mission(seed)
        rec = run_inprocess(mission, seed).record
        emu, emu_start_ne_m = _fly_in_memory(mission, seed)
        out[seed] = (rec.connected[: mission.run.n_steps], emu, rec.pos_m[0], emu_start_ne_m)
    return out


def test_both_backends_start_from_the_same_spawn_and_measure_the_same_instants(runs):
    for seed, (inproc, emu, start_in, start_emu) in runs.items():
        assert inproc.shape == emu.shape == (40, 3), seed
        # the emulated vehicles took off vertically from the same ring (spawn noise 2 m)
        assert np.abs(start_in - start_emu).max() < 0.1, seed


def test_the_transient_agrees_seed_by_seed(runs):
    """Until every task is first connected, the two backends count the same tasks (+-1 step)."""
    for seed, (inproc, emu, _, _) in runs.items():
        assert inproc[0].sum() < 3, "the mission must start with tasks out of reach (else vacuous)"
        first_in = [int(np.argmax(inproc[:, j])) for j in range(3)]
        first_emu = [int(np.argmax(emu[:, j])) for j in range(3)]
        assert inproc.any(0).all() and emu.any(0).all(), seed
        assert np.abs(np.subtract(first_in, first_emu)).max() <= 1, (seed, first_in, first_emu)


def test_tu1_tu2_agree(runs):
    d1, d2, same = [], [], []
    for seed, (inproc, emu, _, _) in runs.items():
        (a1, a2), (b1, b2) = _tu(inproc), _tu(emu)
        d1.append(b1 - a1)
        d2.append(b2 - a2)
        same.append(float(np.mean(inproc.sum(1) == emu.sum(1))))
        assert abs(d1[-1]) <= 0.12 and abs(d2[-1]) <= 0.12, (seed, a1, b1, a2, b2)
    assert abs(np.mean(d1)) <= 0.04 and abs(np.mean(d2)) <= 0.04, (d1, d2)
    assert np.mean(same) >= 0.85, same
