"""One mission scenario (mission.format.scenario) and one world loop (mission.experiments.world_loop)."""

import numpy as np
import pytest

from mission.format.load import loads_mission
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.format.scenario import MissionScenario, build_scenario, loss_probability, track_at
from mission.experiments.world_loop import run_world
from planner.methods import make_planner
from planner.problem import problem_preset
from vehicle_emu.world import World, draw_scenario, spawn_streams

MISSION = """
name: scenario
vehicles:
  emulated: {count: 5, spawn: {ring: {radius_m: 20, noise_m: 3}}}
tasks:
  - track: [{t_s: 0, north_m: 100, east_m: 0}, {t_s: 10, north_m: 0, east_m: 100}]
  - random_walk: {start: {north_m: -50, east_m: 20}, sigma_m_per_sqrt_s: 2}
attrition:
  rate_per_s: 0.02
  scripted: [{vehicle: 3, t_s: 4.5}]
  hazard_zones:
    - {circle: {center: {north_m: 0, east_m: 0}, radius_m: 30}, rate_per_s: 0.5, start_s: 2}
run: {duration_s: 10, control_period_s: 1, seed: 7}
"""


def test_the_emulated_flight_and_the_playback_draw_one_scenario():
    m = loads_mission(MISSION)
    a, b = build_scenario(m, 7), mission_scenario(m, 7)
    assert isinstance(b, MissionScenario)
    for name in ("spawn_ne_m", "task_track_m", "attrition_u", "scripted_step"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.task_names == b.task_names == ["task 0", "task 1"]
    assert a.scripted_step.tolist() == [-1, -1, -1, 4, -1]
    # the emulator's world draws its losses from the scenario's uniforms
    world = MissionWorld(m, b, build_swarm(m, b, seed=7))
    assert world._attrition_u is b.attrition_u
    assert not np.array_equal(build_scenario(m, 8).attrition_u, a.attrition_u)


def test_task_positions_are_exact_at_the_steps_linear_between_and_held_at_the_ends():
    track = np.arange(12.0).reshape(3, 2, 2)  # 3 steps, 2 tasks
    scn = MissionScenario(np.zeros((1, 2)), track, 2.0)
    assert np.array_equal(scn.task_pos_m(4.0), track[2])
    assert np.array_equal(scn.task_pos_m(2.0), track[1])
    assert np.allclose(scn.task_pos_m(3.0), (track[1] + track[2]) / 2)
    assert np.array_equal(scn.task_pos_m(-5.0), track[0])
    assert np.array_equal(scn.task_pos_m(99.0), track[2])
    assert np.array_equal(track_at(track[:1], 1.0, 3.0), track[0])  # one sample: constant


def test_step_loss_probability_is_the_zones_plus_the_scripted_step():
    m = loads_mission(MISSION)
    scn = build_scenario(m)
    pos = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 10.0], [200.0, 0.0], [0.0, -200.0]])
    for t in range(m.run.n_steps):
        p = scn.step_loss_probability(t, pos)
        ref = loss_probability(m, t * 1.0, pos)
        assert np.array_equal(scn.loss_probability(t * 1.0, pos), ref)
        assert p[3] == (1.0 if t == 4 else ref[3])
        assert np.array_equal(np.delete(p, 3), np.delete(ref, 3))
    assert scn.loss_probability(0.0, pos)[0] == pytest.approx(-np.expm1(-0.02))
    assert scn.loss_probability(2.0, pos)[0] == pytest.approx(-np.expm1(-0.52))


def test_run_world_reports_every_loss_once_in_order():
    problem = problem_preset("XS", 0.05)
    streams = spawn_streams(11)
    scenario = draw_scenario(problem, streams)
    world = World.from_scenario(problem, scenario)
    planner = make_planner("phireman", problem, {}, streams.algorithm)
    run = run_world(
        world,
        planner,
        problem.n_steps,
        problem.attrition_per_step,
        scenario.attrition_u,
        record=True,
    )
    rec = run.record
    assert run.losses, "5 % per step over the horizon: some drone is lost"
    assert [t for t, _ in run.losses] == sorted(t for t, _ in run.losses)
    for t, i in run.losses:
        assert rec.alive[t, i] and not rec.alive[t + 1, i]
    assert len(run.losses) == int((~rec.alive[-1]).sum())
    assert np.array_equal(run.alive_count, rec.alive[:-1].sum(1))
    assert np.array_equal(run.active_count, rec.active[:-1].sum(1))
    assert rec.connected is run.connected and rec.trees == {}


def test_with_batteries_the_emulators_drones_on_the_ground_are_safe_from_attrition():
    """As in the paper's world with endurance (world_loop: grounded drones, p_loss 0): a spare on
    the ground is never drawn; without batteries every live vehicle is, as before."""
    batteries = "\nendurance: {battery: {endurance_s: 1500}}\n"
    for text, ground_safe in ((MISSION, False), (MISSION + batteries, True)):
        m = loads_mission(text.replace("rate_per_s: 0.02", "rate_per_s: 5.0"))
        scn = mission_scenario(m, 7)
        swarm = build_swarm(m, scn, seed=7)
        world = MissionWorld(m, scn, swarm)
        ph = swarm.physics
        ph.armed[:] = [True, True, False, False, False]
        ph.landed[:] = [False, False, True, True, True]
        world.start(0.0)
        world.poll(0.9)
        lost = {i for _, i, cause in world.losses if cause == "attrition"}
        assert {0, 1} <= lost  # certain losses (rate 5 per second) in the air
        assert bool(lost & {2, 4}) is not ground_safe  # 3 is scripted
