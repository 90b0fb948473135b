"""The information model: what a planner knows at each tick ('central' or message passing).

A planner that supports both models (:mod:`planner.phireman`, :mod:`planner.dccrs`,
:mod:`planner.resilient`) takes one parameter, ``info`` (:data:`INFO_MODELS`), validated by
:func:`check_info`, and asks the model built by :func:`information_model` for a per-tick view:

* ``central`` (:class:`CentralInfo` -> :class:`CentralView`): one planner sees D'(t), the
  networked drones, with their true positions; every networked drone is planned jointly and holds
  this tick's base broadcast (the ground station's view; docs/design/architecture.md §3.2).
* ``async`` (:class:`MessagePassingInfo` -> :class:`MessageView`): the paper's message passing
  (docs/design/model.md §5.4, :class:`planner.knowledge.MessageLayer`): drone i plans from its own
  table of neighbour reports (entries: holder, drone, believed position) and its own copy of the
  base broadcast (a task tree, or DCCRS's task positions) at the stamp it last received; a drone
  whose copy is older than ``tree_stale_steps`` assumes disconnection and heads home.

What each model decides for the planners, once, here:

* which drones are planned this tick (``view.planned``) and the instructions the model itself
  gives (``view.disp_u``: zero, or home for the stale drones of the async model);
* what each planned drone believes about its peers and the base's broadcast;
* the speed-limit rule the descent may use (:func:`resolve_speed_rule`): 'uniform' (one joint stop
  at the limit) needs one planner for all drones, so it is central's; independent drones can only
  stop each on its own ('per_drone').

Which model a *run* uses is decided by its caller: the planner's default is the paper's
(:data:`PAPER_INFO`, what ``phireman sim`` and the sweeps run); a mission's ``planner.info``
(default :data:`STATION_INFO`) is passed by the ground station and the in-process playback through
:func:`planner.methods.params_with_info`. MCCST is central only (:data:`planner.methods.INFO_OF`).

All positions are paper units (:mod:`planner.units`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from planner.units import PaperUnits

if TYPE_CHECKING:  # the message layer (SciPy, Numba) is imported when a run first uses it, so that
    # the names here (INFO_MODELS, ...) cost planner.methods and mission.format.schema nothing
    from planner.knowledge import MessageLayer

__all__ = [
    "INFO_MODELS",
    "PAPER_INFO",
    "STATION_INFO",
    "SPEED_RULES",
    "check_info",
    "check_speed_rule",
    "resolve_speed_rule",
    "MessageTiming",
    "CentralView",
    "MessageView",
    "CentralInfo",
    "MessagePassingInfo",
    "InfoModel",
    "information_model",
]

#: The information models, by the name of the ``info`` parameter.
INFO_MODELS = ("async", "central")

#: The paper's information model: the planners' default (``phireman sim``, the sweeps).
PAPER_INFO = "async"

#: The ground station's: a mission plans with it unless its ``planner.info`` says otherwise.
STATION_INFO = "central"

#: The descent's speed-limit rules (planner.phireman.descend); 'auto' is resolved per model.
SPEED_RULES = ("auto", "uniform", "per_drone", "clip")

#: What 'auto' means under each information model (see :func:`resolve_speed_rule`).
_AUTO_SPEED_RULE = {"central": "uniform", "async": "per_drone"}


def check_info(info: str) -> None:
    """Raise ValueError unless ``info`` names an information model."""
    if info not in INFO_MODELS:
        raise ValueError(f"info must be one of {INFO_MODELS}, got {info!r}")


def check_speed_rule(speed_rule: str) -> None:
    """Raise ValueError unless ``speed_rule`` is one of :data:`SPEED_RULES`."""
    if speed_rule not in SPEED_RULES:
        raise ValueError(f"speed_rule must be one of {SPEED_RULES}, got {speed_rule!r}")


def resolve_speed_rule(speed_rule: str, info: str) -> str:
    """The descent's speed rule under ``info``: 'auto' is 'uniform' for central (one planner stops
    every drone together at the limit, docs/design/model.md §9.3) and 'per_drone' for async
    (independent drones each stop at their own limit or equilibrium); other rules as given."""
    return _AUTO_SPEED_RULE[info] if speed_rule == "auto" else speed_rule


class MessageTiming(Protocol):
    """The message-layer parameters a planner's params carry (PhiremanParams, DccrsParams)."""

    @property
    def age_max_steps(self) -> int: ...
    @property
    def dist_max(self) -> float: ...
    @property
    def tree_stale_steps(self) -> int: ...
    @property
    def broadcast_after_move(self) -> bool: ...
    @property
    def forget_unheard(self) -> bool: ...


@dataclass(frozen=True)
class CentralView:
    """One tick under central information."""

    planned: np.ndarray
    """(n,) int: the drones planned (networked and alive), ascending."""
    disp_u: np.ndarray
    """(N, 2) float: instructions, zero (the planner fills the planned rows)."""
    held_stamp: np.ndarray
    """(N,) int: the tick of the last base broadcast each drone received (this tick for the
    planned ones; -1 = never)."""
    prev_pos_u: np.ndarray | None
    """(N, 2): every drone's true position at the previous tick (None at the first tick), so the
    planner knows each drone's last executed displacement."""

    def info(self) -> dict[str, Any]:
        """Diagnostics of the model for ``PlanOutput.info`` (none under central information)."""
        return {}


@dataclass(frozen=True)
class MessageView:
    """One tick under message passing (entries are the planned drones' table entries)."""

    planned: np.ndarray
    """(n,) int: the drones planned (networked, alive and holding a fresh broadcast), ascending."""
    disp_u: np.ndarray
    """(N, 2) float: instructions; the stale drones' rows already head home at full speed."""
    held_stamp: np.ndarray
    """(N,) int: the stamp of the base broadcast each drone holds (-1 = never received)."""
    n_stale: int
    """Networked drones whose broadcast copy went stale (sent home)."""
    rows_e: np.ndarray
    """(E,) int: the holder of each entry, an index into ``planned``, row-major order."""
    cols_e: np.ndarray
    """(E,) int: the drone of each entry, an index into ``layer.knowledge.cols``."""
    believed_u: np.ndarray
    """(E, 2): the holder's belief of that drone's position."""
    stamps: np.ndarray
    """(n,) int: the broadcast stamp each planned drone holds."""
    layer: MessageLayer
    """The message layer (the tables behind the entries)."""
    whole: bool = False
    """The entries are the layer's whole view this tick (every alive drone planned): entry e is
    the knowledge's view entry e."""

    def info(self) -> dict[str, Any]:
        """Diagnostics of the model for ``PlanOutput.info``."""
        return {"stale_tree": self.n_stale}

    def entry_stamps(self) -> np.ndarray | None:
        """(E,) the stamp each entry's holder holds of its drone (what
        :meth:`believed_displacement_u` looks up), when the entries are the whole view of a
        :class:`planner.knowledge.Knowledge`; else None."""
        from planner.knowledge import Knowledge

        kn = self.layer.knowledge
        if not (self.whole and isinstance(kn, Knowledge)):
            return None
        return kn.view_entry_stamps()

    def broadcasts(self) -> tuple[list[Any], np.ndarray]:
        """The broadcast versions the planned drones hold, oldest first, and (n,) which one each
        planned drone holds (an index into that list)."""
        versions, version_of = np.unique(self.stamps, return_inverse=True)
        return [self.layer.broadcast(s) for s in versions], version_of

    def believed_displacement_u(self, holders: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(E, 2): the last executed displacement of drone ``cols[e]`` (into
        ``layer.knowledge.cols``) as known to drone ``holders[e]`` (a drone id): pos(s) - pos(s-1)
        for the holder's stamp s of it; 0 if s < 1 (planner.dccrs.believed_velocities, per entry)."""
        from planner import _message_kernels  # imported with the message layer (see above)
        from planner.knowledge import Knowledge

        kn = self.layer.knowledge
        assert kn.cols is not None  # set by the knowledge update
        col_e = kn.cols[cols]
        if isinstance(kn, Knowledge) and kn.pos_hist_m.shape[1] == kn.n_drones:
            fast = _message_kernels.believed_displacement(
                kn.held_rows,
                kn.held_cols,
                kn.held_stamps,
                kn.n_drones,
                holders,
                col_e,
                kn.pos_hist_m,
            )
            if fast is not None:  # the lines below in one compiled pass (the same bits)
                return fast
        stamp_e = kn.stamp[holders, col_e]
        s = np.where(stamp_e >= 1, stamp_e, 1)
        return np.where(
            (stamp_e >= 1)[:, None], kn.pos_hist_m[s, col_e] - kn.pos_hist_m[s - 1, col_e], 0.0
        )


class CentralInfo:
    """Central information over a run: remembers the previous tick and who holds which broadcast."""

    name = "central"

    def __init__(self, units: PaperUnits) -> None:
        self.units = units
        self._held_stamp: np.ndarray | None = None
        self._prev_pos_u: np.ndarray | None = None

    def see(
        self,
        t_step: int,
        pos_u: np.ndarray,
        alive: np.ndarray,
        planning: np.ndarray,
        base_u: np.ndarray,
        broadcast: object,
    ) -> CentralView:
        """This tick's view: ``planning`` (N,) bool, the networked and alive drones; ``broadcast``
        (what the base sends, unused: every planned drone holds the current one)."""
        del alive, base_u, broadcast  # the central planner reads the truth directly
        n = len(pos_u)
        planned = np.flatnonzero(planning)
        held = self._held_stamp
        if held is None or len(held) != n:
            grown = np.full(n, -1, dtype=np.int64)
            if held is not None:
                keep = min(n, len(held))
                grown[:keep] = held[:keep]
            held = self._held_stamp = grown
        held[planned] = t_step
        prev = self._prev_pos_u
        self._prev_pos_u = pos_u
        return CentralView(
            planned,
            np.zeros_like(pos_u),
            held,
            prev if prev is not None and len(prev) == n else None,
        )


class MessagePassingInfo:
    """The paper's message passing over a run (the :class:`MessageLayer`, built at the first tick
    for the drones it sees)."""

    name = "async"

    def __init__(self, units: PaperUnits, n_steps: int, timing: MessageTiming) -> None:
        self.units = units
        self.n_steps = n_steps
        self.timing = timing
        self.layer: MessageLayer | None = None

    def see(
        self,
        t_step: int,
        pos_u: np.ndarray,
        alive: np.ndarray,
        planning: np.ndarray,
        base_u: np.ndarray,
        broadcast: object,
    ) -> MessageView:
        """Deliver last tick's messages, record the base's ``broadcast`` (what each drone then
        plans from), send the stale drones home and return the planned drones' entries."""
        u = self.units
        if self.layer is None:
            from planner.knowledge import MessageLayer

            self.layer = MessageLayer.from_params(
                len(pos_u), self.n_steps, u.radio_range_u, u.base_reach_u, self.timing
            )
        layer = self.layer
        # Stale broadcast: assume disconnection and fly to the known base location at full speed.
        stale, disp_u = layer.step_or_home(
            t_step, pos_u, alive, base_u, broadcast, planning, u.max_step_u
        )
        planned = np.flatnonzero(planning & ~stale)
        n_stale = int(stale.sum())
        if len(planned) == 0:
            none = np.zeros(0, dtype=np.int64)
            return MessageView(
                planned,
                disp_u,
                layer.knowledge.tree_stamp,
                n_stale,
                none,
                none,
                np.zeros((0, 2)),
                none,
                layer,
            )
        rows_e, cols_e, believed_u, stamps = layer.view_entries(planned)
        kn_rows = layer.knowledge.rows
        return MessageView(
            planned,
            disp_u,
            layer.knowledge.tree_stamp,
            n_stale,
            rows_e,
            cols_e,
            believed_u,
            stamps,
            layer,
            kn_rows is not None
            and len(kn_rows) == len(planned)
            and bool(np.array_equal(kn_rows, planned)),
        )


InfoModel = CentralInfo | MessagePassingInfo


def information_model(
    info: str, units: PaperUnits, n_steps: int, timing: MessageTiming
) -> InfoModel:
    """The model named ``info`` for a planner over a run of ``n_steps`` ticks (the message layer's
    history grows if a run outlasts it) with the message timing of its parameters."""
    check_info(info)
    if info == "central":
        return CentralInfo(units)
    return MessagePassingInfo(units, n_steps, timing)
