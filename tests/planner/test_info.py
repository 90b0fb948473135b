"""The information model (planner.info), paper units (planner.units) and how methods take ``info``."""

from __future__ import annotations

import numpy as np
import pytest

from planner.dccrs import DccrsPlanner
from planner.info import (
    INFO_MODELS,
    PAPER_INFO,
    STATION_INFO,
    CentralInfo,
    CentralView,
    MessagePassingInfo,
    MessageView,
    check_info,
    resolve_speed_rule,
)
from planner.knowledge import MessageLayer
from planner.methods import INFO_OF, METHODS, TickInput, info_models, make_planner, params_with_info
from planner.mccst import MccstPlanner
from planner.phireman import PhiremanParams, PhiremanPlanner
from planner.problem import problem_preset
from planner.resilient import ResilientPlanner
from planner.units import PaperUnits

BOTH = ("phireman", "phireman-no-task", "phireman-nodes-only", "dccrs", "phireman-resilient")


def test_every_method_says_which_information_models_it_plans_with():
    assert set(INFO_OF) == set(METHODS)
    assert all(set(models) <= set(INFO_MODELS) and models for models in INFO_OF.values())
    assert info_models("mccst") == ("central",)
    assert info_models("phireman-central") == ("central",)
    for name in BOTH:
        assert info_models(name) == INFO_MODELS
    assert PAPER_INFO == "async" and STATION_INFO == "central"


@pytest.mark.parametrize("name", BOTH)
@pytest.mark.parametrize("info", INFO_MODELS)
def test_the_two_model_planners_take_info_the_same_way(name, info):
    problem = problem_preset("XS", 0.0)
    planner = make_planner(name, problem, {"info": info})
    assert planner.params.info == info  # type: ignore[attr-defined]
    model = planner.info_model  # type: ignore[attr-defined]
    assert isinstance(model, CentralInfo if info == "central" else MessagePassingInfo)
    # 'auto' resolved in one place: one joint stop (central), one per drone (async)
    assert planner.params.speed_rule == ("uniform" if info == "central" else "per_drone")  # type: ignore[attr-defined]
    # default: the paper's model
    assert make_planner(name, problem, {}).params.info == PAPER_INFO  # type: ignore[attr-defined]


def test_central_only_methods_accept_central_and_refuse_async():
    problem = problem_preset("XS", 0.0)
    assert isinstance(make_planner("mccst", problem, {"info": "central"}), MccstPlanner)
    with pytest.raises(ValueError, match="central information only"):
        make_planner("mccst", problem, {"info": "async"})
    pc = make_planner("phireman-central", problem, {"info": "central"})
    assert isinstance(pc, PhiremanPlanner) and pc.params.info == "central"
    with pytest.raises(ValueError, match="central information only"):
        make_planner("phireman-central", problem, {"info": "async"})
    with pytest.raises(ValueError, match="info must be one of"):
        make_planner("phireman", problem, {"info": "telepathy"})


def test_params_with_info_sets_the_model_or_checks_it():
    assert params_with_info("dccrs", {"leader_gain": 0.1}, "async") == {
        "leader_gain": 0.1,
        "info": "async",
    }
    assert params_with_info("phireman", None, "central") == {"info": "central"}
    assert params_with_info("mccst", {"k_p": 1.0}, "central") == {"k_p": 1.0}
    assert params_with_info("phireman-central", {}, "central") == {}
    with pytest.raises(ValueError, match="central information only"):
        params_with_info("mccst", {}, "async")
    with pytest.raises(ValueError, match="params ask for info='async'"):
        params_with_info("phireman", {"info": "async"}, "central")


def test_speed_rule_and_info_checks():
    assert resolve_speed_rule("auto", "central") == "uniform"
    assert resolve_speed_rule("auto", "async") == "per_drone"
    assert resolve_speed_rule("clip", "central") == "clip"
    check_info("async")
    with pytest.raises(ValueError):
        check_info("central ")
    with pytest.raises(ValueError, match="speed_rule"):
        PhiremanParams(speed_rule="fast")


@pytest.mark.parametrize("size", ["XS", "M", "XL"])
def test_paper_units_are_the_planners_earlier_arithmetic(size):
    problem = problem_preset(size, 0.01).replace(
        base_range_m=1.5 * problem_preset(size).length_unit_m
    )
    u = PaperUnits.of(problem)
    unit = problem.length_unit_m
    assert u.unit_m == unit
    assert u.radio_range_u == problem.radio_range_m / unit == 2.0
    assert u.base_reach_u == min(problem.base_range_m, problem.radio_range_m) / unit
    assert u.max_step_u == problem.max_speed_m_s * problem.dt_s / unit
    x_m = np.random.default_rng(0).normal(0, 10 * unit, (7, 2))
    np.testing.assert_array_equal(u.to_u(x_m), np.asarray(x_m, float) / unit)
    np.testing.assert_array_equal(u.to_m(u.to_u(x_m)), (x_m / unit) * unit)
    assert u.tree_to_m(None) is None


def test_central_view_plans_the_networked_and_remembers_the_last_tick():
    units = PaperUnits.of(problem_preset("XS", 0.0))
    info = CentralInfo(units)
    pos0 = np.arange(8.0).reshape(4, 2)
    planning = np.array([True, False, True, True])
    v0 = info.see(0, pos0, np.ones(4, bool), planning, np.zeros(2), object())
    assert isinstance(v0, CentralView)
    np.testing.assert_array_equal(v0.planned, [0, 2, 3])
    np.testing.assert_array_equal(v0.disp_u, np.zeros((4, 2)))
    np.testing.assert_array_equal(v0.held_stamp, [0, -1, 0, 0])
    assert v0.prev_pos_u is None and v0.info() == {}
    v1 = info.see(1, pos0 + 1, np.ones(4, bool), ~planning, np.zeros(2), object())
    np.testing.assert_array_equal(v1.planned, [1])
    np.testing.assert_array_equal(v1.held_stamp, [0, 1, 0, 0])
    np.testing.assert_array_equal(v1.prev_pos_u, pos0)
    # a fleet that changed size: no previous positions to difference against
    v2 = info.see(2, np.zeros((5, 2)), np.ones(5, bool), np.ones(5, bool), np.zeros(2), object())
    assert v2.prev_pos_u is None and len(v2.held_stamp) == 5


def test_message_view_is_the_message_layer():
    """The view hands the planners exactly what the message layer says."""
    problem = problem_preset("XS", 0.0)
    units = PaperUnits.of(problem)
    p = PhiremanParams(tree_stale_steps=2)
    info = MessagePassingInfo(units, problem.n_steps, p)
    ref = MessageLayer.from_params(6, problem.n_steps, units.radio_range_u, units.base_reach_u, p)
    rng = np.random.default_rng(1)
    pos = rng.uniform(-1.5, 1.5, (6, 2))
    pos[5] = (30.0, 30.0)  # never hears anybody
    alive = np.ones(6, bool)
    planning = np.ones(6, bool)
    base = np.zeros(2)
    for t in range(5):
        payload = f"tree {t}"
        view = info.see(t, pos, alive, planning, base, payload)
        assert isinstance(view, MessageView)
        stale, disp = ref.step_or_home(t, pos, alive, base, payload, planning, units.max_step_u)
        planned = np.flatnonzero(planning & ~stale)
        np.testing.assert_array_equal(view.planned, planned)
        np.testing.assert_array_equal(view.disp_u, disp)
        assert view.info() == {"stale_tree": int(stale.sum())}
        if len(planned):
            er, ek, believed, stamps = ref.view_entries(planned)
            np.testing.assert_array_equal(view.rows_e, er)
            np.testing.assert_array_equal(view.cols_e, ek)
            np.testing.assert_array_equal(view.believed_u, believed)
            held, which = view.broadcasts()
            assert [held[k] for k in which] == [ref.broadcast(s) for s in stamps]
        pos = pos + 0.05
    assert 5 not in view.planned and np.linalg.norm(view.disp_u[5]) > 0  # stale: heading home


@pytest.mark.parametrize(
    "cls,name",
    [
        (PhiremanPlanner, "phireman"),
        (DccrsPlanner, "dccrs"),
        (ResilientPlanner, "phireman-resilient"),
    ],
)
def test_planners_report_the_async_model_and_plan_nothing_for_the_unplanned(cls, name):
    problem = problem_preset("XS", 0.0)
    rng = np.random.default_rng(3)
    pos = rng.uniform(-1, 1, (problem.n_drones, 2)) * problem.length_unit_m
    tasks = rng.uniform(-3, 3, (problem.n_tasks, 2)) * problem.length_unit_m
    alive = np.ones(problem.n_drones, bool)
    networked = alive.copy()
    networked[:3] = False
    for info in INFO_MODELS:
        planner = make_planner(name, problem, {"info": info})
        assert isinstance(planner, cls)
        out = planner.plan(TickInput(0, pos, alive, networked, tasks))
        assert ("stale_tree" in out.info) == (info == "async")  # the message layer ran
        np.testing.assert_array_equal(out.disp_m[:3], 0.0)
        assert np.all(
            np.linalg.norm(out.disp_m, axis=1) <= problem.max_speed_m_s * problem.dt_s * (1 + 1e-12)
        )
