"""What the base of ``phireman-resilient`` has heard: the mesh as the message layer delivers it.

Issue 28. The redundancy (planner/redundancy.py) and the coverage claims (planner/resilient.py)
are decided by the base, from the mesh of the networked drones and the crews it hears. Under the
paper's asynchronous model (docs/design/model.md §5.4) nothing reaches the base except through
the drones' radio messages, so here the base's picture is built from *reports* that travel the
way every message of that model travels:

* At each step every alive drone makes a report stamped with the step: its own position (a drone
  knows where it is), the drones it heard in that step's delivery (its neighbour list: the radio
  links the message layer used, :attr:`planner.knowledge.Knowledge.last_delivery`) and the crews
  it hears (tasks strictly within r of it, docs/design/model.md §4).
* Reports are flooded with the layer's rules: a drone broadcasts the freshest report it holds of
  each drone, its radio neighbours receive them at the next delivery (one hop per step, only
  over the links of that delivery, only alive drones forward, a lost drone's table is lost), and
  the base receives what the drones within its reach broadcast (the links over which it sends
  its tree, ``Knowledge.update``). A report older than ``max_age_steps`` is neither forwarded
  nor kept. The planner uses the tree's staleness bound (``tree_stale_steps``, 15): the bound
  the model already sets for messages that must cross the swarm's hop diameter (the tree going
  out); the neighbour tables' ``age_max_steps`` (3) and ``dist_max`` cut-offs are about what a
  drone needs for its own potential and do not apply to these reports.
* The base's mesh: the drones whose report it holds, each at the position of its report; a link
  where *both* ends' reports list each other (the two-way check of link-state routing, so a
  lost drone drops out as soon as a neighbour's newer report arrives); the base's own links are
  the drones it hears now. The drones it believes networked are the base's component of that
  mesh, and the crews it hears are those some of them report.

So a drone h hops out is seen where it was h - 1 steps ago (with the default broadcast after
moving, one step earlier otherwise), a drone whose reports cannot reach the base within
``max_age_steps`` hops is not seen at all, and a lost drone is believed alive until the reports
around it say otherwise.

Computing the base's stamps. The freshest report of drone k at the base at step t is the
largest s such that a journey over the deliveries s, s + 1, ..., t (one hop per delivery, waiting
allowed) leads from k to the base, s >= t - max_age_steps. :class:`BaseListener` finds it
backwards: the set of drones from which a report held before delivery tau still reaches the base
by t grows by one hop per delivery, from the base's neighbours at t back to t - max_age_steps
(a loop over at most ``max_age_steps`` + 1 deliveries, vectorised over the links), and a
drone's stamp is the last delivery before which it joined the set. :func:`heard_reference` floods
every drone's table forward, entry by entry, exactly as the message layer does (the slow
reference; ``tests/planner/test_base_view.py`` compares the two).

Lengths in paper units, like the message layer's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from planner.geometry import neighbour_pairs
from planner.knowledge import Knowledge
from planner.redundancy import MeshGraph, mesh_from_links

__all__ = ["HeardMesh", "BaseListener", "heard_reference"]


@dataclass(frozen=True)
class HeardMesh:
    """The base's picture of the mesh at one step (everything it could have heard).

    Attributes
    ----------
    stamp : (N,) int, the step of the freshest report the base holds of each drone (-1: none)
    pos_u : (N, 2) float, each drone's position in that report (NaN: none)
    edges : (E, 2) int, the links both ends' reports list (drone ids, i < j, sorted)
    at_base : (N,) bool, the drones the base hears directly at this step
    networked : (N,) bool, the base's component of its mesh (what it believes is D'(t))
    crews : (M,) bool, the tasks some drone of ``networked`` reports hearing
    crew_pairs : (C, 2) int, (drone, task) for each crew a networked drone reports
    """

    stamp: np.ndarray
    pos_u: np.ndarray
    edges: np.ndarray
    at_base: np.ndarray
    networked: np.ndarray
    crews: np.ndarray
    crew_pairs: np.ndarray

    def graph(self) -> MeshGraph:
        """The mesh of the drones the base believes networked, for planner.redundancy."""
        rows = np.flatnonzero(self.networked)
        local = np.full(len(self.networked), -1, np.int64)
        local[rows] = np.arange(len(rows))
        e = self.edges[self.networked[self.edges[:, 0]] & self.networked[self.edges[:, 1]]]
        at_base = local[np.flatnonzero(self.at_base & self.networked)]
        n_tasks = len(self.crews)
        cp = self.crew_pairs
        if n_tasks == 0:
            return mesh_from_links(rows, local[e], at_base, [])
        # For each task, its attached nodes, sorted (one sort, then a split per task).
        order = np.lexsort((local[cp[:, 0]], cp[:, 1]))
        node_sorted, task_sorted = local[cp[order, 0]], cp[order, 1]
        cuts = np.searchsorted(task_sorted, np.arange(1, n_tasks))
        task_nodes = [a.astype(np.int64) for a in np.split(node_sorted, cuts)]
        return mesh_from_links(rows, local[e], at_base, task_nodes)


@dataclass(frozen=True)
class _Delivery:
    """One delivery of the message layer: the drones linked (alive at link time), their links
    (P, 2) into ``idx`` and which of them the base heard (within its reach at link time)."""

    idx: np.ndarray
    pairs: np.ndarray
    at_base: np.ndarray


class BaseListener:
    """Collects the deliveries of a :class:`planner.knowledge.MessageLayer` and the reports they
    carry, and gives the base's picture of the mesh (:class:`HeardMesh`) at each step.

    Parameters
    ----------
    max_age_steps : reports older than this are neither forwarded nor kept
    after_move : the layer's ``broadcast_after_move`` (when in a step a report is made: a report
        stamped s first travels in delivery s when True, in delivery s + 1 when False)
    radio_range_u, base_reach_u : link range r (a crew is heard strictly within it) and the
        base's reach min(R, r)
    """

    def __init__(
        self, max_age_steps: int, after_move: bool, radio_range_u: float, base_reach_u: float
    ) -> None:
        if max_age_steps < 0:
            raise ValueError(f"max_age_steps must be >= 0, got {max_age_steps}")
        self.max_age_steps = int(max_age_steps)
        self.after_move = bool(after_move)
        self.radio_range_u = float(radio_range_u)
        self.base_reach_u = float(base_reach_u)
        self._deliveries: dict[int, _Delivery] = {}
        self._crews: dict[int, np.ndarray] = {}  # report stamp -> (C, 2) (drone, task)
        self._pos_hist: np.ndarray | None = None

    def record(
        self,
        t_step: int,
        knowledge: Knowledge,
        pos_u: np.ndarray,
        alive: np.ndarray,
        tasks_u: np.ndarray,
        base_u: np.ndarray,
    ) -> None:
        """After the layer's step ``t_step``: keep its delivery (the links) and this step's reports
        (each alive drone's crews, at its position ``pos_u``)."""
        t = int(t_step)
        d = knowledge.last_delivery
        if d is not None and d[0] == t:
            _, idx, pairs, link_pos = d
            at_base = (
                np.linalg.norm(np.asarray(link_pos)[idx] - base_u, axis=1) <= self.base_reach_u
            )
            self._deliveries[t] = _Delivery(
                np.asarray(idx, np.int64), np.asarray(pairs, np.int64).reshape(-1, 2), at_base
            )
        a = np.flatnonzero(np.asarray(alive, bool))
        tasks_u = np.asarray(tasks_u, float).reshape(-1, 2)
        if len(a) and len(tasks_u):
            dist = np.linalg.norm(pos_u[a, None, :] - tasks_u[None, :, :], axis=2)  # (n, M)
            dr, tk = np.nonzero(dist < self.radio_range_u)
            self._crews[t] = np.column_stack([a[dr], tk]).astype(np.int64)
        else:
            self._crews[t] = np.zeros((0, 2), np.int64)
        self._pos_hist = knowledge.pos_hist_m
        keep = t - self.max_age_steps - 1
        for old in [s for s in self._deliveries if s < keep]:
            del self._deliveries[old]
        for old in [s for s in self._crews if s < keep]:
            del self._crews[old]

    def stamps(self, t_step: int, n_drones: int) -> np.ndarray:
        """(N,) int: the stamp of the freshest report of each drone the base holds after the
        delivery of ``t_step`` (-1: none). A loop over the deliveries (at most max_age_steps +
        1), vectorised over the links."""
        t = int(t_step)
        stamp = np.full(n_drones, -1, np.int64)
        reach = np.zeros(n_drones, bool)  # a report held here before delivery tau reaches the base
        shift = (
            0 if self.after_move else 1
        )  # a report stamped s first travels in delivery s + shift
        for tau in range(t, t - self.max_age_steps - 1 + shift, -1):
            d = self._deliveries.get(tau)
            if d is None:  # nothing delivered at the first step: no older report can arrive
                break
            a, b = d.idx[d.pairs[:, 0]], d.idx[d.pairs[:, 1]]
            new = reach.copy()
            new[d.idx[d.at_base]] = True
            new[a[reach[b]]] = True  # one hop: from the set as it was after tau
            new[b[reach[a]]] = True
            reach = new
            stamp[reach & (stamp < 0)] = tau - shift
        return stamp

    def heard(self, t_step: int, n_drones: int, n_tasks: int) -> HeardMesh:
        """The base's picture after the delivery of ``t_step`` (see the module docstring)."""
        t = int(t_step)
        stamp = self.stamps(t, n_drones)
        pos = np.full((n_drones, 2), np.nan)
        known = np.flatnonzero(stamp >= 0)
        if len(known):
            assert self._pos_hist is not None  # recorded with the deliveries
            pos[known] = self._pos_hist[stamp[known], known]
        # Each report lists its drone's links in the delivery of its stamp; keep the two-way ones.
        src_l, dst_l = [], []
        for s in np.unique(stamp[known]):  # loop over report stamps (<= max_age_steps + 1)
            d = self._deliveries.get(int(s))
            if d is None:
                continue
            a, b = d.idx[d.pairs[:, 0]], d.idx[d.pairs[:, 1]]
            ka, kb = stamp[a] == s, stamp[b] == s
            src_l += [a[ka], b[kb]]
            dst_l += [b[ka], a[kb]]
        src = np.concatenate(src_l) if src_l else np.zeros(0, np.int64)
        dst = np.concatenate(dst_l) if dst_l else np.zeros(0, np.int64)
        lo, hi = np.minimum(src, dst), np.maximum(src, dst)
        keys, count = np.unique(lo * n_drones + hi, return_counts=True)
        two_way = keys[count == 2]
        edges = np.column_stack([two_way // n_drones, two_way % n_drones]).astype(np.int64)
        at_base = np.zeros(n_drones, bool)
        d_now = self._deliveries.get(t)
        if d_now is not None:
            at_base[d_now.idx[d_now.at_base]] = True
        # The base's component (node n_drones = the base).
        b = np.flatnonzero(at_base)
        src = np.concatenate([edges[:, 0], b])
        dst = np.concatenate([edges[:, 1], np.full(len(b), n_drones)])
        adj = coo_matrix(
            (np.ones(len(src), np.int8), (src, dst)), shape=(n_drones + 1, n_drones + 1)
        ).tocsr()
        _, label = connected_components(adj, directed=False)
        networked = (label[:n_drones] == label[n_drones]) & (stamp >= 0)
        # The crews the networked drones report (each report's own crews).
        pairs_l = []
        for s in np.unique(stamp[networked]):
            cp = self._crews.get(int(s))
            if cp is None or len(cp) == 0:
                continue
            pairs_l.append(cp[(stamp[cp[:, 0]] == s) & networked[cp[:, 0]]])
        crew_pairs = np.concatenate(pairs_l) if pairs_l else np.zeros((0, 2), np.int64)
        crews = np.zeros(n_tasks, bool)
        crews[crew_pairs[:, 1]] = True
        return HeardMesh(stamp, pos, edges, at_base, networked, crews, crew_pairs)


def heard_reference(
    pos_hist: np.ndarray,
    alive_hist: np.ndarray,
    tasks_hist: np.ndarray,
    t_step: int,
    radio_range: float,
    base_reach: float,
    base: np.ndarray,
    max_age_steps: int,
    after_move: bool,
) -> HeardMesh:
    """The base's picture at ``t_step`` by flooding every drone's table of reports forward,
    entry by entry, from step 0 (plain loops; the reference of :class:`BaseListener`).

    Parameters
    ----------
    pos_hist, alive_hist, tasks_hist : (T, N, 2), (T, N), (T, M, 2): true positions, alive flags
        and task positions of steps 0 .. t_step (at least)
    radio_range, base_reach, base : links (<=), the base's reach (<=) and position
    max_age_steps, after_move : as :class:`BaseListener`
    """
    n = pos_hist.shape[1]
    m = tasks_hist.shape[1]
    age = int(max_age_steps)
    table: list[dict[int, int]] = [{} for _ in range(n)]  # holder -> {drone: stamp}
    base_table: dict[int, int] = {}
    links_of: dict[int, list[tuple[int, int]]] = {}  # delivery -> links (drone ids)
    base_nbrs: dict[int, list[int]] = {}
    for t in range(t_step + 1):
        alive = alive_hist[t]
        if after_move:
            for i in range(n):  # own report first, then the hop
                if not alive[i]:
                    table[i] = {}
                else:
                    table[i][i] = t
        if t > 0:
            lt = t if after_move else t - 1  # links and positions of the delivery
            t_sent = lt
            la = alive_hist[lt]
            ids = [i for i in range(n) if la[i]]
            pr = (
                neighbour_pairs(pos_hist[lt][ids], radio_range)
                if len(ids) > 1
                else np.zeros((0, 2), np.int64)
            )
            links = [(ids[int(i)], ids[int(j)]) for i, j in pr]
            links_of[t] = links
            base_nbrs[t] = [i for i in ids if np.linalg.norm(pos_hist[lt][i] - base) <= base_reach]
            sent = [{k: s for k, s in table[i].items() if s >= t_sent - age} for i in range(n)]
            new = [dict(sent[i]) for i in range(n)]
            for i, j in links:
                for a, b in ((i, j), (j, i)):
                    for k, s in sent[b].items():
                        if s > new[a].get(k, -1):
                            new[a][k] = s
            table = new
            for i in base_nbrs[t]:
                for k, s in sent[i].items():
                    if s > base_table.get(k, -1):
                        base_table[k] = s
        for i in range(n):
            if not alive[i]:
                table[i] = {}
            elif not after_move:
                table[i][i] = t
            table[i] = {k: s for k, s in table[i].items() if s >= t - age}
        base_table = {k: s for k, s in base_table.items() if s >= t - age}
    stamp = np.full(n, -1, np.int64)
    pos = np.full((n, 2), np.nan)
    for k, s in base_table.items():
        stamp[k], pos[k] = s, pos_hist[s][k]

    def nbrs(k: int) -> set[int]:
        s = int(stamp[k])
        out = set()
        for i, j in links_of.get(s, []):
            if i == k:
                out.add(j)
            elif j == k:
                out.add(i)
        return out

    heard_nbrs = {k: nbrs(k) for k in base_table}
    edges = sorted(
        (i, j) for i in heard_nbrs for j in heard_nbrs[i] if i < j and i in heard_nbrs.get(j, ())
    )
    at_base = np.zeros(n, bool)
    at_base[base_nbrs.get(t_step, [])] = True
    networked = np.zeros(n, bool)
    todo = [i for i in range(n) if at_base[i] and stamp[i] >= 0]
    for i in todo:
        networked[i] = True
    while todo:
        i = todo.pop()
        for a, b in edges:
            j = b if a == i else a if b == i else -1
            if j >= 0 and not networked[j]:
                networked[j] = True
                todo.append(j)
    crew_pairs = []
    for k in range(n):
        if networked[k]:
            s = int(stamp[k])
            for task in range(m):
                if np.linalg.norm(pos_hist[s][k] - tasks_hist[s][task]) < radio_range:
                    crew_pairs.append((k, task))
    crews = np.zeros(m, bool)
    for _, task in crew_pairs:
        crews[task] = True
    return HeardMesh(
        stamp,
        pos,
        np.array(edges, np.int64).reshape(-1, 2),
        at_base,
        networked,
        crews,
        np.array(crew_pairs, np.int64).reshape(-1, 2),
    )
