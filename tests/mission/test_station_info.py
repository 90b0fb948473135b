"""Which information model a mission plans with: decided once (PlannerSpec.run_params) and used
the same way by the ground station (``phireman fly``) and the in-process playback.

The station plans with central information unless the mission's ``planner.info`` says otherwise;
``method: dccrs`` with ``info: async`` really runs the message-passing model in the station.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import mission.experiments.playback as playback
import mission.flight.station_loop as station_loop
from small_mission import crew, small_mission
from mission.flight.ether import LockstepEther, station_for_swarm
from mission.flight.fly_options import FlyOptions
from mission.format.load import validate_mission
from mission.flight.mission_world import MissionWorld, build_swarm, mission_scenario
from mission.format.schema import (
    INFO_MODES,
    PlannerSpec,
    RunSpec,
)
from mission.flight.station_loop import make_operator
from planner.info import INFO_MODELS, STATION_INFO, CentralInfo, MessagePassingInfo


def _mission(method="phireman", info=None, n=4, duration_s=12.0, **params):
    planner = (
        PlannerSpec(method=method, params=params)
        if info is None
        else PlannerSpec(method=method, info=info, params=params)
    )
    return small_mission(
        "info",
        RunSpec(duration_s=duration_s, control_period_s=1.0, seed=3),
        count=n,
        tasks=(crew(60.0, 40.0), crew(-50.0, -60.0)),
        planner=planner,
    )


def _fly(mission, seed=3, limit_s=200.0):
    """A whole flight: operator + station + emulated swarm in memory on a virtual clock."""
    scenario = mission_scenario(mission, seed)
    swarm = build_swarm(mission, scenario, seed=seed)
    world = MissionWorld(mission, scenario, swarm)
    station = station_for_swarm(swarm)
    op = make_operator(
        mission, scenario, station, FlyOptions(wave_size=10), mission.vehicles.count, 0.0, seed
    )
    ether = LockstepEther(swarm, station, np.random.default_rng(seed))
    ether.on_event = op.handle_event
    started = False

    def poll(now):
        nonlocal started
        op.poll(now)
        if not started and op.mission_t0_s is not None:
            started = True
            world.start(op.mission_t0_s)

    while op.phase != "done" and ether.now_s < limit_s:
        ether.advance_to(ether.now_s + 1.0, poll=poll, poll_period_s=0.5)
    assert op.phase == "done", op.phase
    return op


def test_the_schema_spells_the_planner_models_and_defaults_to_the_stations():
    assert set(INFO_MODES) == set(INFO_MODELS)
    assert PlannerSpec().info == STATION_INFO == "central"


@pytest.mark.parametrize("method", ["dccrs", "phireman"])
def test_station_flies_with_message_passing_when_the_mission_says_async(method):
    op = _fly(_mission(method, "async"))
    model = op.planner.info_model
    assert isinstance(model, MessagePassingInfo)
    assert op.planner.params.info == "async"
    # the message layer ran every planned tick: the tables hold what the drones told each other
    assert model.layer is not None
    planned = [r for r in op.records if r.planned]
    assert len(planned) >= 10
    assert (
        model.layer.knowledge.entry_rows is not None and len(model.layer.knowledge.entry_rows) > 0
    )
    assert (model.layer.knowledge.tree_stamp >= 0).all()


@pytest.mark.parametrize("method", ["phireman", "dccrs", "phireman-resilient", "phireman-no-task"])
def test_station_plans_centrally_by_default(method):
    m = _mission(method)
    assert m.planner.info == "central"
    scenario = mission_scenario(m, 3)
    op = make_operator(
        m, scenario, station_for_swarm(build_swarm(m, scenario, seed=3)), FlyOptions(), 4, 0.0, 3
    )
    assert isinstance(op.planner.info_model, CentralInfo) and op.planner.params.info == "central"


def test_station_flies_central_dccrs_by_default():
    op = _fly(_mission("dccrs"))
    assert isinstance(op.planner.info_model, CentralInfo)
    assert sum(1 for r in op.records if r.planned) >= 10


@pytest.mark.parametrize(
    "method,info",
    [
        ("phireman", "async"),
        ("phireman", "central"),
        ("dccrs", "async"),
        ("dccrs", "central"),
        ("mccst", "central"),
        ("phireman-resilient", "async"),
    ],
)
def test_station_and_playback_build_the_same_planner(monkeypatch, method, info):
    """One decision: the station and the in-process playback pass make_planner the same params."""
    m = _mission(method, info, duration_s=3.0)
    seen = {}

    def spy(where):
        real = where.make_planner

        def make(name, problem, params=None, rng=None):
            seen.setdefault(where.__name__, []).append((name, dict(params or {})))
            return real(name, problem, params, rng)

        return make

    monkeypatch.setattr(station_loop, "make_planner", spy(station_loop))
    monkeypatch.setattr(playback, "make_planner", spy(playback))
    scenario = mission_scenario(m, 3)
    make_operator(
        m, scenario, station_for_swarm(build_swarm(m, scenario, seed=3)), FlyOptions(), 4, 0.0, 3
    )
    playback.run_inprocess(m, seed=3)
    expected = m.planner.run_params()
    assert seen["mission.flight.station_loop"] == [(method, expected)]
    assert seen["mission.experiments.playback"] == [(method, expected)]
    assert expected.get("info", "central") == info


def test_a_mission_cannot_ask_a_central_only_method_for_async_nor_set_info_twice():
    with pytest.raises(Exception, match="central information only"):
        validate_mission(_mission("mccst", "async"))
    with pytest.raises(Exception, match="planner.info"):
        validate_mission(
            dataclasses.replace(_mission("phireman"), planner=PlannerSpec(params={"info": "async"}))
        )
    assert validate_mission(_mission("mccst")).planner.run_params() == {}
