"""The row ``phireman fly`` prints its status line from (mission/commands/fly.py
``format_status``), for the tests of that line: a running mission of 50 vehicles, 40 networked,
8 lost, 2 returning, 9 crews of 10 covered; a test overrides what it checks."""

from __future__ import annotations


def status_row(**kw) -> dict:
    d = dict(
        phase="run",
        t_s=120.0,
        end_t0_s=None,
        t_mission_s=100.0,
        duration_s=200.0,
        fleet=50,
        fleet_expected=50,
        networked=40,
        lost=8,
        returning=2,
        tasks_covered=9,
        n_tasks=10,
        tu1=0.71,
        tu2=0.77,
        modes={"GUIDED": 40, "LOST": 8, "RTL": 2},
        command_failures=0,
        failsafes=0,
        last_failsafe=None,
        reclaims=3,
        speedup=20.0,
        wall_s=0.0,
    )
    d.update(kw)
    return d
