"""What the step mixins (audit, launch, end, operator actions) use of :class:`Operator`: its state
(set up in ``Operator.__init__``) and the methods one step calls on another, declared for the
type checker only. At run time the class is empty, so nothing here changes the operator's MRO or
behaviour.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from gcs import audit as audit_mod
    from gcs.control import ControlConfig
    from gcs.fleet import FleetSnapshot, FleetView
    from gcs.operations.config import OperationsConfig, OperatorAction, _Row
    from gcs.operations.phases import Phase, Trigger
    from gcs.operations.rotation_setup import RotationSetup
    from gcs.rally import RallyKeeper
    from gcs.station import Station

__all__ = ["OperatorState"]


class OperatorState:
    """Base of the step mixins: declarations only (see the module docstring)."""

    if TYPE_CHECKING:
        station: Station
        fleet: FleetView
        control: ControlConfig
        config: OperationsConfig
        gcs_sysid: int
        refusal: str | None
        _phase: Phase
        _phase_since_s: float
        _rows: dict[int, _Row]
        _params: dict[tuple[int, int], dict[str, float]]
        _params_pending: set[tuple[int, int, str]]
        _last_param_s: float
        _known: set[tuple[int, int]]
        _audit_vids: set[tuple[int, int]]
        audit_report: audit_mod.AuditReport | None
        initial_audit_report: audit_mod.AuditReport | None
        param_changes: list[dict[str, Any]]
        _param_types: dict[tuple[int, int], dict[str, int]]
        _sets_pending: set[tuple[int, int, str]]
        _fixes_sent_s: float | None
        _limits_sent_s: float | None
        _restore_sent_s: float | None
        _rally_params_sent_s: float | None
        rally: RallyKeeper | None
        limit_warnings: list[str]
        prearm: dict[tuple[int, int], tuple[float, str]]
        _audit_round: int
        _waves: list[list[int]]
        _launch_since_s: float
        _launch_gave_up: bool
        _wave: int
        _wave_since_s: float
        mission_t0_s: float | None
        _next_tick_s: float
        _t_step: int
        end_t0_s: float | None
        reclaimed: list[tuple[float, int, int]]
        counters: dict[str, int]
        released: dict[tuple[int, int], str]
        overrides: dict[tuple[int, int], OperatorAction]
        _refusals_logged: dict[tuple[int, int], tuple[float, str, str]]

        def t_mission_s(self, now_s: float) -> float: ...

        interrupted: str | None
        end_status: dict[str, int] | None
        actions: list[OperatorAction]
        on_action: Callable[[OperatorAction], None] | None
        rotation: RotationSetup | None

        @property
        def phase(self) -> Phase: ...
        @phase.setter
        def phase(self, value: str) -> None: ...
        def _enter(self, trigger: Trigger, now_s: float) -> None: ...
        def _vid(self, snap: FleetSnapshot, i: int) -> tuple[int, int]: ...
        def _in_plan(self, snap: FleetSnapshot) -> np.ndarray: ...
        # One step calling another.
        def _set_param(
            self,
            vid: tuple[int, int],
            name: str,
            value: float,
            previous: float | None,
            purpose: str,
            now_s: float,
        ) -> bool: ...
        def _audit_gate(self, snap: FleetSnapshot) -> np.ndarray: ...
        def _late_audit_heard(self, vid: tuple[int, int], t_s: float) -> bool: ...
        def _audit_names(
            self, autopilot: int, got: dict[str, float], *, first: bool
        ) -> list[str]: ...
        def _optional_param(self, name: str) -> bool: ...
        def _audit_report(
            self,
            vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]],
            *,
            override: bool = False,
        ) -> audit_mod.AuditReport: ...
        def _write_fixes(
            self, vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]], now_s: float
        ) -> audit_mod.AuditReport: ...
        def _send_limits(
            self, vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]], now_s: float
        ) -> bool: ...
        def _send_rally_params(
            self, vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]], now_s: float
        ) -> bool: ...
        def _limits_wanted(self) -> bool: ...
        def _start_launch(self, snap: FleetSnapshot, now_s: float, trigger: Trigger) -> None: ...
        def _hold(self, snap: FleetSnapshot, rows: npt.ArrayLike, now_s: float) -> None: ...
        def begin_end(self, now_s: float) -> None: ...
        def _send_targets(
            self, snap: FleetSnapshot, rows: np.ndarray, target_ned_m: np.ndarray, now_s: float
        ) -> int: ...
        def _send_layer_targets(
            self, snap: FleetSnapshot, rows: np.ndarray, target_ne_m: np.ndarray, now_s: float
        ) -> int: ...
        def _climb_before_rtl(self, snap: FleetSnapshot, i: int, now_s: float) -> bool: ...
        def _rotation_may_fly(self, n: int) -> np.ndarray: ...
        def _rotation_landing_params(self, autopilot: int) -> tuple[str, ...]: ...
        def _rotation_use_landing(
            self, vehicles: dict[tuple[int, int], tuple[int, dict[str, float]]]
        ) -> None: ...
        def _rotation_confirm_swap(self, i: int, now_s: float) -> str: ...
        def _rally_holds_end(self, vid: tuple[int, int], now_s: float) -> bool: ...
