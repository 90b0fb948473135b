"""The relay rotation on the operator's page (live and replay): the frame's ``rotation`` key.

Built from the rotation's state (:meth:`gcs.operations.rotation_setup.RotationSetup.state`: the
station's own, live; the last line of the run directory's ``rotation.jsonl`` at that instant,
replayed), its events, and the fleet snapshot of the frame (the spares' and relays' positions,
for the ETA). What the page shows (``static/rotation.js``, docs/live_view.md):

* each vehicle's rotation phase (``phase``, one entry per frame row, as ``v.id``);
* the queue: who is relieving whom with the spare's distance and ETA (``queue``), then the relays
  in the plan with no spare yet, by the time to their reserve (``due``);
* the pads: the vehicle on each, its swap's elapsed and nominal remaining time, the swap request
  and the ground crew's confirmation (``pads``); the vehicles waiting for a pad (``waiting``);
* the base's batteries: charged on the shelf, the charging ones' remaining times, the ones
  waiting for a charger (``batteries``); the counters (``counters``) and the latest rotation
  events in words (``events``).

Times in the state are absolute (station core seconds); here they become seconds from the
frame's instant.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["rotation_frame", "event_text", "MAX_DUE", "MAX_EVENTS"]

#: At most this many relays are listed by their time to reserve.
MAX_DUE = 5
#: The panel lists this many of the latest rotation events.
MAX_EVENTS = 12


def _label(vid: str | None) -> str:
    """``"0:7"`` -> ``"7"``, ``"1:7"`` -> ``"1:7"`` (the page's vehicle labels)."""
    if vid is None:
        return "?"
    link, _, sysid = vid.partition(":")
    return sysid if link == "0" else vid


def event_text(ev: dict[str, Any]) -> str:
    """One rotation event (``RotationSetup.event_dicts``) in words."""
    d, o = f"vehicle {_label(ev.get('vehicle'))}", f"vehicle {_label(ev.get('other'))}"
    return {
        "launch": f"{d} launched to relieve {o}",
        "handover": f"{d} took over {o}'s post",
        "return": f"{d} relieved by {_label(ev.get('other'))}: flying home",
        "forced_return": f"{d} at its reserve with no spare: flying home",
        "landed": f"{d} landed at the base",
        "swap_start": f"swap requested: {d} on a pad",
        "crew_confirmed": f"the ground crew confirmed {d}'s swap",
        "swap_done": f"{d} swapped: a charged spare again",
        "no_spare": f"no spare ready to relieve {d}",
        "no_battery": f"{d} waits for a charged battery",
        "pad_wait": f"{d} waits for a free pad",
        "lost": f"{d} lost to the rotation",
        "failsafe_return": f"{d}: battery failsafe, its firmware sends it home",
        "relaunch": f"{d} relaunched into the plan",
        "refill": f"{d} launched into a post lost in the air",
    }.get(str(ev.get("kind")), f"{d}: {ev.get('kind')}")


def _secs(x: float) -> int | None:
    return None if not math.isfinite(x) else int(round(x))


def rotation_frame(
    state: dict[str, Any],
    events: list[dict[str, Any]],
    snap,
    t_s: float,
    mission_t0_s: float | None,
) -> dict[str, Any]:
    """The frame's ``rotation`` key (module docstring).

    Parameters
    ----------
    state : the rotation's state at (or just before) ``t_s``
    events : rotation events up to ``t_s`` (the latest :data:`MAX_EVENTS` are shown)
    snap : the frame's :class:`gcs.fleet.FleetSnapshot` (rows as the frame's ``v``)
    t_s : the frame's instant, station core seconds
    mission_t0_s : when the mission began (events are stamped in mission time), or None
    """
    ids = [f"{l}:{s}" for l, s in zip(snap.link_id.tolist(), snap.sysid_of_index.tolist())]
    row = {vid: i for i, vid in enumerate(ids)}
    phase_of = dict(zip(state["vehicles"], state["phase"]))
    ne = snap.pos_ned_m[:, :2]
    has = snap.has_position

    def pos(vid: str) -> np.ndarray | None:
        i = row.get(vid)
        return None if i is None or not has[i] else ne[i]

    speed = float(state.get("return_speed_m_s") or 0.0)
    queue = []
    for spare, relay in state["inbound"]:
        a, b = pos(spare), pos(relay)
        dist = None if a is None or b is None else float(np.hypot(*(b - a)))
        eta = None if dist is None or not speed > 0 else _secs(dist / speed)
        queue.append(
            {
                "spare": spare,
                "relay": relay,
                "dist_m": None if dist is None else int(round(dist)),
                "eta_s": eta,
            }
        )
    due = sorted(
        (
            {"relay": vid, "reserve_in_s": max(0, int(round(at - t_s)))}
            for vid, at in state["reserve_at_s"].items()
        ),
        key=lambda x: x["reserve_in_s"],
    )[:MAX_DUE]
    swap_s = float(state["swap_time_s"])
    pads = []
    for k, p in enumerate(state["pads"]):
        if p.get("vehicle") is None:
            pads.append({"pad": k + 1, "vehicle": None})
            continue
        elapsed = max(0.0, t_s - float(p["since_s"]))
        pads.append(
            {
                "pad": k + 1,
                "vehicle": p["vehicle"],
                "elapsed_s": int(elapsed),
                "left_s": max(0, int(math.ceil(swap_s - elapsed))),
                "confirmed": p.get("confirmed_s") is not None,
            }
        )
    batt = state["batteries"]
    t0 = 0.0 if mission_t0_s is None else mission_t0_s
    shown = []
    for ev in events[-MAX_EVENTS:]:
        shown.append(
            {
                "t_mission_s": None if mission_t0_s is None else round(ev["t_s"] - t0, 1),
                "kind": ev["kind"],
                "vehicle": ev.get("vehicle"),
                "text": event_text(ev),
            }
        )
    return {
        "swap_confirm": state["swap_confirm"],
        "phase": [phase_of.get(vid) for vid in ids],
        "queue": queue,
        "due": due,
        "pads": pads,
        "swap_time_s": swap_s,
        "waiting": [
            v for v, ph in zip(state["vehicles"], state["phase"]) if ph in ("landed", "no_battery")
        ],
        "batteries": {
            "charged": int(batt["charged"]),
            "charging_left_s": [max(0, int(math.ceil(t - t_s))) for t in batt["charging_done_s"]],
            "queued": int(batt["queued"]),
            "chargers": int(batt["chargers"]),
        },
        "counters": state["counters"],
        "events": shown,
    }
