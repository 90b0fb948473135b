"""Redundancy against single losses: which relays are critical, and which spare doubles each.

Part of ``phireman-resilient`` (planner/resilient.py, issue 15). Under attrition a task stays
connected only while every drone on its one path to the base survives; a single loss of a *cut
vertex* (articulation point of the mesh) cuts every task behind it until the swarm re-forms the
chain. Here the base finds, each tick, the networked drones whose loss alone would cut tasks and
pulls a nearby *spare* (a networked drone no connected task needs) onto each of them, so that
the chain has a second drone where a loss would hurt most.

Information: the functions here take a mesh and positions and do not care where they come
from. ``phireman-resilient`` gives them, under the asynchronous model, the mesh its base has heard
through the message layer (planner/base_view.py: each drone's reported position and neighbour
list, delayed one step per hop; :func:`mesh_from_links`), or with ``base_view='oracle'`` the true
positions and mesh of this tick (:func:`mesh_graph`), as under central information (issue 28;
planner/resilient.py says what the base knows in each case). It broadcasts one target per
assigned spare with its task tree; a drone acts on the copy it holds.

* :func:`critical_counts` - for each networked drone, how many connected tasks its loss alone
  would cut: Tarjan's low-point depth-first search on the mesh, rooted at the base, then one walk
  per task up the search tree. :func:`critical_counts_reference` removes each drone in turn.
* :func:`backbone` - the drones on a shortest hop path from the base to each connected task; the
  others are the spares.
* :class:`RedundancyBook` - the spare-to-relay pairs, kept from tick to tick (a pair whose spare
  has made its relay non-critical must not be undone the next tick).

Lengths in any one unit (the planner passes paper units). Links: drone-drone ``<= r``, base-drone
``<= base_reach``, task-drone ``< r`` (planner/geometry.py: ``active_mask``, ``tasks_connected``).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import breadth_first_order
from scipy.spatial import cKDTree

from planner._graph_kernels import _jit
from planner.geometry import active_mask_reference, tasks_connected

__all__ = [
    "MeshGraph",
    "mesh_graph",
    "mesh_from_links",
    "critical_counts",
    "critical_counts_reference",
    "backbone",
    "RedundancyBook",
]


class MeshGraph:
    """The networked drones' mesh with the base as node ``k`` (CSR adjacency).

    Attributes
    ----------
    rows : (k,) int - the drone (row of the tick's arrays) of each node 0..k-1
    indptr, indices : CSR adjacency over k + 1 nodes (node k = base)
    task_nodes : list of (a,) int arrays - for each task, the nodes strictly within r of it
    """

    def __init__(
        self,
        rows: np.ndarray,
        indptr: np.ndarray,
        indices: np.ndarray,
        task_nodes: list[np.ndarray],
    ):
        self.rows = rows
        self.indptr = indptr
        self.indices = indices
        self.task_nodes = task_nodes

    @property
    def n_nodes(self) -> int:
        return len(self.rows) + 1

    @property
    def base(self) -> int:
        return len(self.rows)


def mesh_graph(
    pos: np.ndarray,
    networked: np.ndarray,
    tasks: np.ndarray,
    base: np.ndarray,
    r: float,
    base_reach: float,
) -> MeshGraph:
    """The mesh of the networked drones (links ``<= r``), the base linked to the drones within
    ``base_reach``, and each task's attached drones (``< r``)."""
    rows = np.flatnonzero(np.asarray(networked, bool))
    p = np.asarray(pos, float)[rows]
    k = len(rows)
    kd = cKDTree(p) if k else None
    pairs = kd.query_pairs(r, output_type="ndarray") if kd is not None and k > 1 else None
    if pairs is None:
        pairs = np.zeros((0, 2), np.int64)
    at_base = np.flatnonzero(np.linalg.norm(p - base, axis=1) <= base_reach)
    task_nodes: list[np.ndarray] = []
    if kd is not None and len(tasks):
        near = kd.query_ball_point(np.asarray(tasks, float), r)
        for t, cand in enumerate(near):
            cand = np.asarray(cand, dtype=np.int64)
            d = np.linalg.norm(p[cand] - tasks[t], axis=1) if len(cand) else np.zeros(0)
            task_nodes.append(np.sort(cand[d < r]))
    else:
        task_nodes = [np.zeros(0, np.int64) for _ in range(len(tasks))]
    return mesh_from_links(rows, pairs, at_base, task_nodes)


def mesh_from_links(
    rows: np.ndarray, pairs: np.ndarray, at_base: np.ndarray, task_nodes: list[np.ndarray]
) -> MeshGraph:
    """The mesh over given links (not measured from positions): what :func:`mesh_graph` builds
    once it has its links, and what the base of ``phireman-resilient`` builds from the reports it
    has heard (planner/base_view.py).

    Parameters
    ----------
    rows : (k,) int, the drone (row of the tick's arrays) of each node 0..k-1
    pairs : (P, 2) int, links between nodes (indices into ``rows``), each once
    at_base : (B,) int, the nodes linked to the base (node k)
    task_nodes : for each task, the nodes attached to it (sorted)
    """
    k = len(rows)
    pairs = np.asarray(pairs).reshape(-1, 2)
    at_base = np.asarray(at_base)
    src = np.concatenate([pairs[:, 0], pairs[:, 1], at_base, np.full(len(at_base), k)])
    dst = np.concatenate([pairs[:, 1], pairs[:, 0], np.full(len(at_base), k), at_base])
    adj = coo_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(k + 1, k + 1)).tocsr()
    adj.sort_indices()
    return MeshGraph(rows, adj.indptr, adj.indices, task_nodes)


def _cut_counts(
    indptr: np.ndarray,
    indices: np.ndarray,
    root: int,
    task_ptr: np.ndarray,
    task_att: np.ndarray,
) -> np.ndarray:
    """Per node, the tasks its loss alone cuts (Numba-compatible: arrays and loops only).

    Tarjan's depth-first search from ``root`` (iterative, explicit stack) gives each node its
    discovery time, low point, parent and depth; then one walk per task: the lowest common
    ancestor of its reached attachments, the check at that ancestor, and the climb to the root.
    """
    n = len(indptr) - 1
    disc = np.full(n, -1, np.int64)
    low = np.zeros(n, np.int64)
    parent = np.full(n, -1, np.int64)
    depth = np.zeros(n, np.int64)
    stack_v = np.empty(n, np.int64)
    stack_i = np.empty(n, np.int64)
    disc[root] = 0
    low[root] = 0
    counter = 1
    stack_v[0] = root
    stack_i[0] = indptr[root]
    sp = 1
    while sp > 0:  # each edge is looked at twice
        v = stack_v[sp - 1]
        i = stack_i[sp - 1]
        if i < indptr[v + 1]:
            stack_i[sp - 1] = i + 1
            w = indices[i]
            if disc[w] < 0:
                parent[w] = v
                depth[w] = depth[v] + 1
                disc[w] = counter
                low[w] = counter
                counter += 1
                stack_v[sp] = w
                stack_i[sp] = indptr[w]
                sp += 1
            elif w != parent[v] and disc[w] < low[v]:
                low[v] = disc[w]
        else:
            sp -= 1
            if sp > 0:
                u = stack_v[sp - 1]
                if low[v] < low[u]:
                    low[u] = low[v]
    count = np.zeros(n, np.int64)
    for t in range(len(task_ptr) - 1):
        lca = -1
        for j in range(task_ptr[t], task_ptr[t + 1]):
            a = task_att[j]
            if disc[a] < 0:
                continue
            if lca < 0:
                lca = a
                continue
            while depth[a] > depth[lca]:
                a = parent[a]
            while depth[lca] > depth[a]:
                lca = parent[lca]
            while a != lca:
                a = parent[a]
                lca = parent[lca]
        if lca < 0:
            continue  # not connected now
        if lca != root:
            ok = True
            for j in range(task_ptr[t], task_ptr[t + 1]):
                a = task_att[j]
                if disc[a] < 0 or a == lca:
                    continue
                c = a
                while parent[c] != lca:
                    c = parent[c]
                if low[c] < disc[lca]:
                    ok = False
                    break
            if ok:
                count[lca] += 1
        c = lca
        while c != root:
            v = parent[c]
            if v == root:
                break
            if low[c] >= disc[v]:
                count[v] += 1
            c = v
    return count


_cut_counts_compiled = _jit(_cut_counts)


def critical_counts(g: MeshGraph, n_drones: int, compiled: bool = True) -> np.ndarray:
    """(N,) int: for each drone, the number of tasks connected now that its loss alone would cut.

    Only drones of the base's component count (others and non-networked drones: 0). A task is
    cut by losing v exactly when v separates every drone the task is attached to from the base:
    v is an ancestor-or-self of the attachments' lowest common ancestor in the search tree and,
    for each attachment other than v, the subtree hanging below v toward it has no back edge
    above v (low point >= disc[v]). ``compiled``: the Numba build of the same function (the
    plain one when Numba is missing); tests compare both with :func:`critical_counts_reference`.
    """
    out = np.zeros(n_drones, np.int64)
    if len(g.rows) == 0:
        return out
    sizes = np.array([len(a) for a in g.task_nodes], dtype=np.int64)
    task_ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    task_att = (
        np.concatenate(g.task_nodes).astype(np.int64)
        if len(g.task_nodes)
        else np.zeros(0, np.int64)
    )
    kernel = _cut_counts_compiled if compiled else _cut_counts
    count = kernel(
        g.indptr.astype(np.int64), g.indices.astype(np.int64), g.base, task_ptr, task_att
    )
    out[g.rows] = count[: len(g.rows)]
    return out


def critical_counts_reference(
    pos: np.ndarray,
    networked: np.ndarray,
    tasks: np.ndarray,
    base: np.ndarray,
    r: float,
    base_reach: float,
) -> np.ndarray:
    """Remove each drone in turn and count the tasks that lose their link (for tests)."""
    pos = np.asarray(pos, float)
    net = np.asarray(networked, bool)
    act = active_mask_reference(pos, net, r, base_reach, base)
    now = tasks_connected(tasks, pos, act, r)
    out = np.zeros(len(pos), np.int64)
    for i in np.flatnonzero(act):
        alive = net.copy()
        alive[i] = False
        after = tasks_connected(
            tasks, pos, active_mask_reference(pos, alive, r, base_reach, base), r
        )
        out[i] = int(np.count_nonzero(now & ~after))
    return out


def backbone(g: MeshGraph, n_drones: int) -> np.ndarray:
    """(N,) bool: the drones on a fewest-hop path from the base to each connected task (the task's
    attached drone nearest the base in hops, ties to the lowest row)."""
    out = np.zeros(n_drones, bool)
    if len(g.rows) == 0:
        return out
    n = g.n_nodes
    adj = csr_matrix((np.ones(len(g.indices), np.int8), g.indices, g.indptr), shape=(n, n))
    order, pred = breadth_first_order(adj, g.base, directed=False, return_predecessors=True)
    hops = np.full(g.n_nodes, np.iinfo(np.int64).max, np.int64)
    hops[g.base] = 0
    for v in order[1:]:  # BFS order: parents come first
        hops[v] = hops[pred[v]] + 1
    on = np.zeros(g.n_nodes, bool)
    for att in g.task_nodes:
        att = att[hops[att] < np.iinfo(np.int64).max] if len(att) else att
        if len(att) == 0:
            continue
        v = int(att[np.argmin(hops[att])])
        while v != g.base and not on[v]:
            on[v] = True
            v = int(pred[v])
    out[g.rows] = on[: len(g.rows)]
    return out


class RedundancyBook:
    """The base's spare-to-relay pairs, kept while both stay networked, the relay stays on the
    backbone and the spare stays off it; new pairs go to the most critical uncovered relays.

    ``assign`` returns (N, 2) targets (the relay's position; NaN rows: no target).
    """

    def __init__(self) -> None:
        self.pair_of: dict[int, int] = {}  # spare row -> relay row

    def assign(
        self,
        pos: np.ndarray,
        networked: np.ndarray,
        critical: np.ndarray,
        on_backbone: np.ndarray,
        reach: float,
        min_cut: int = 1,
        priority: np.ndarray | None = None,
    ) -> np.ndarray:
        """Update the pairs and return each spare's target.

        Parameters
        ----------
        pos : (N, 2) positions; networked : (N,) bool
        critical : (N,) int, :func:`critical_counts`; on_backbone : (N,) bool, :func:`backbone`
        reach : a spare is paired only with a relay within this distance
        min_cut : relays cutting fewer tasks get no spare
        priority : (N,) float, optional order key of the relays (default ``critical``; larger first)
        """
        n = len(pos)
        net = np.asarray(networked, bool)
        spare = net & ~np.asarray(on_backbone, bool)
        keep: dict[int, int] = {}
        for s, c in sorted(self.pair_of.items()):
            if s < n and c < n and spare[s] and net[c] and on_backbone[c]:
                keep[s] = c
        covered = set(keep.values())
        key = critical.astype(float) if priority is None else np.asarray(priority, float)
        want = [
            int(c)
            for c in np.flatnonzero(net & (critical >= max(min_cut, 1)))
            if int(c) not in covered
        ]
        want.sort(key=lambda c: (-key[c], c))
        free = np.flatnonzero(spare)
        free = free[~np.isin(free, list(keep))]
        for c in want:  # greedy, most critical first, nearest free spare
            if len(free) == 0:
                break
            d = np.linalg.norm(pos[free] - pos[c], axis=1)
            j = int(np.argmin(d))
            if d[j] > reach:
                continue
            keep[int(free[j])] = c
            free = np.delete(free, j)
        self.pair_of = keep
        out = np.full((n, 2), np.nan)
        for s, c in keep.items():
            out[s] = pos[c]
        return out
