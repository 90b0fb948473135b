"""The semi-Steiner task tree of PhiIREMAN (docs/design/model.md §5.3, §7 #10).

The tree joins the base station B, every task and auxiliary Steiner nodes. Its cost is the paper's

    l_Σ = l_Σe + c_b · l_Σb,

where l_Σe is the total edge length and l_Σb the sum over tasks of the tree-path length from the
task to B; ``base_weight`` is c_b. Higher c_b favours direct routes to the base.

Contents
--------
* :class:`TaskTree`: a rooted tree as two arrays (node positions and parent pointers).
* :func:`fermat_point`, :func:`fermat_points`: exact Fermat (Torricelli) points of triangles, with
  :func:`fermat_point_reference` as a brute-force check.
* :func:`build_task_tree`: greedy Prim-like semi-Steiner insertion, then Fermat refinement.
* :func:`update_task_positions`: move the tasks, keep the topology, relax the Steiner nodes.
* :func:`maintain_task_tree`: the per-tick policy, including the paper's ν acceptance rule.
* :func:`distance_to_tree`: h^T(x), the distance to the union of the edge segments (or to the
  nearest node for the "nodes only" ablation), with :func:`distance_to_tree_reference`.

All positions are 2-D, float64, in metres of the mission frame (north, east); nothing here depends
on the frame's orientation or origin. The module is pure: no clock, no randomness, no I/O.

Size: ~1,000 lines, above the ~600 guideline: the tree, its Fermat geometry (vectorised, scalar and
reference versions), its construction, its per-tick maintenance and the distance to it are one
model (docs/design/model.md §5.3) whose parts share private helpers and are tested together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize

from planner import _graph_kernels, _greedy_kernels, _kernels, _steiner_kernels

__all__ = [
    "TaskTree",
    "fermat_point",
    "fermat_points",
    "fermat_point_reference",
    "build_task_tree",
    "tree_cost",
    "update_task_positions",
    "maintain_task_tree",
    "distance_to_tree",
    "distance_to_tree_reference",
]

_SQRT3 = math.sqrt(3.0)
_TINY = float(np.finfo(np.float64).tiny)

# A Steiner node that ends up within this distance of a neighbour (relative to its neighbourhood's
# size) is treated as coinciding with it and spliced out. Exact ties are already caught by the
# ≥ 120° vertex test; this only removes near-zero edges left by rounding.
_COINCIDE_RTOL = 1e-12

# Weiszfeld iterations for Steiner nodes of degree ≥ 4 (rare: only when a later task attaches
# directly to a Steiner node, or after a splice).
_WEISZFELD_MAX_ITER = 100


# --------------------------------------------------------------------------------------------
# The tree
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TaskTree:
    """A semi-Steiner task tree rooted at the base station.

    Node order is fixed: node 0 is the base B, nodes ``1 .. n_tasks`` are the tasks in task order
    (node ``1 + k`` is task ``k``), and nodes ``n_tasks + 1 ..`` are Steiner nodes. Both arrays are
    copied to float64 / int64 and made read-only on construction; every function here returns a new
    tree.

    Raises
    ------
    ValueError
        If the shapes disagree, ``parent[0] != -1``, a parent index is out of range, or the parent
        pointers contain a cycle (some node does not reach node 0).
    """

    nodes_m: np.ndarray
    """(K, 2) float64: node positions, metres. Row 0 base, rows 1..n_tasks tasks, then Steiner."""
    parent: np.ndarray
    """(K,) int64: parent index of each node; ``parent[0] == -1`` (the base is the root)."""
    n_tasks: int
    """Number of task nodes (m)."""

    def __post_init__(self) -> None:
        nodes = np.array(self.nodes_m, dtype=np.float64)
        parent = np.array(self.parent, dtype=np.int64)
        if nodes.ndim != 2 or nodes.shape[1] != 2 or len(nodes) < 1:
            raise ValueError(f"nodes_m must be (K, 2) float64 with K >= 1, got shape {nodes.shape}")
        if not np.all(np.isfinite(nodes)):
            raise ValueError("nodes_m must be finite")
        k = len(nodes)
        if parent.shape != (k,):
            raise ValueError(f"parent must be ({k},) int64, got shape {parent.shape}")
        n_tasks = int(self.n_tasks)
        if not 0 <= n_tasks <= k - 1:
            raise ValueError(f"n_tasks must be in [0, {k - 1}], got {self.n_tasks}")
        if parent[0] != -1:
            raise ValueError(f"parent[0] must be -1 (the base is the root), got {parent[0]}")
        if k > 1 and (parent[1:].min() < 0 or parent[1:].max() >= k):
            raise ValueError(f"parent indices must lie in [0, {k - 1}]")
        # Raises on a cycle (some node never reaches the root); compiled O(K) walk when available.
        rooted = _graph_kernels.reaches_root(parent)
        if rooted is None:
            _root_path_lengths(parent, _edge_lengths(nodes, parent))
        elif not rooted:
            raise ValueError("parent pointers contain a cycle: not every node reaches the base")
        nodes.setflags(write=False)
        parent.setflags(write=False)
        object.__setattr__(self, "nodes_m", nodes)
        object.__setattr__(self, "parent", parent)
        object.__setattr__(self, "n_tasks", n_tasks)

    @property
    def n_nodes(self) -> int:
        """K, the number of nodes (base + tasks + Steiner nodes)."""
        return len(self.nodes_m)

    @property
    def n_steiner(self) -> int:
        """Number of Steiner nodes."""
        return self.n_nodes - 1 - self.n_tasks

    @property
    def is_steiner(self) -> np.ndarray:
        """(K,) bool: True for Steiner nodes."""
        return np.arange(self.n_nodes) > self.n_tasks

    @property
    def edges(self) -> np.ndarray:
        """(K-1, 2) int64: ``(child, parent)`` index pairs, one per non-root node, by child."""
        child = np.arange(1, self.n_nodes, dtype=np.int64)
        return np.stack([child, self.parent[1:]], axis=1)

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Edge segments as ``(a_m, b_m)``, each (K-1, 2) float64 metres: child end, parent end.

        Row e matches row e of :attr:`edges`.
        """
        return self.nodes_m[1:].copy(), self.nodes_m[self.parent[1:]]

    def scaled(self, factor: float) -> TaskTree:
        """This tree with its node positions times ``factor`` (paper units <-> metres, used by
        :meth:`planner.units.PaperUnits.tree_to_m`): ``dataclasses.replace(tree, nodes_m=
        tree.nodes_m * factor)`` without checking again the parent pointers it shares (read-only,
        already checked); the positions must stay finite."""
        nodes = np.asarray(self.nodes_m * float(factor), dtype=np.float64)
        if not np.isfinite(nodes).all():
            raise ValueError("nodes_m must be finite")
        nodes.setflags(write=False)
        out = object.__new__(TaskTree)
        object.__setattr__(out, "nodes_m", nodes)
        object.__setattr__(out, "parent", self.parent)
        object.__setattr__(out, "n_tasks", self.n_tasks)
        return out

    def edge_lengths_m(self) -> np.ndarray:
        """(K,) float64: length of the edge to each node's parent, metres (0 for the base)."""
        return _edge_lengths(self.nodes_m, self.parent)

    def path_to_base_m(self) -> np.ndarray:
        """(K,) float64: tree-path length from each node to the base, metres."""
        return _root_path_lengths(self.parent, self.edge_lengths_m())


def _edge_lengths(nodes_m: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """(K,) length of each node's parent edge; 0 for the root."""
    par = np.where(parent < 0, 0, parent)
    diff = nodes_m - nodes_m[par]
    return np.sqrt(np.einsum("kd,kd->k", diff, diff))


def _root_path_lengths(parent: np.ndarray, edge_len_m: np.ndarray) -> np.ndarray:
    """(K,) path length to node 0 by pointer jumping (O(K log K)); ValueError on a cycle.

    After iteration i, ``length[v]`` sums the 2^i edges above v (or all of them) and ``jump[v]`` is
    v's 2^i-th ancestor; the root is a fixed point with length 0.
    """
    k = len(parent)
    jump = parent.astype(np.int64, copy=True)
    jump[0] = 0
    length = edge_len_m.astype(np.float64, copy=True)
    length[0] = 0.0
    for _ in range(max(1, k).bit_length() + 1):
        if not np.any(jump):
            return length
        length = length + length[jump]  # both right-hand terms use the old arrays
        jump = jump[jump]
    if np.any(jump):
        raise ValueError("parent pointers contain a cycle: not every node reaches the base")
    return length


# --------------------------------------------------------------------------------------------
# Fermat points
# --------------------------------------------------------------------------------------------


def _fermat_scalar(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float
) -> tuple[float, float, int]:
    """Fermat point of one triangle in plain floats: ``(x, y, vertex)``, vertex -1 if interior.

    Same formulas as :func:`_fermat_complex` (see :func:`fermat_points`); kept scalar because the
    Gauss-Seidel sweeps call it once per Steiner node, where NumPy's per-call overhead would
    dominate.
    """
    abx, aby = bx - ax, by - ay
    acx, acy = cx - ax, cy - ay
    bcx, bcy = cx - bx, cy - by
    scale = max(math.hypot(abx, aby), math.hypot(acx, acy))
    if scale == 0.0:
        return ax, ay, 0
    # Work in units of the longest side at a, so the weights cannot overflow or underflow.
    abx, aby, acx, acy, bcx, bcy = (v / scale for v in (abx, aby, acx, acy, bcx, bcy))
    cross = abs(abx * acy - aby * acx)  # twice the area
    den_a = cross + _SQRT3 * (abx * acx + aby * acy)  # 2|AB||AC| sin(A + 60°)
    den_b = cross - _SQRT3 * (abx * bcx + aby * bcy)  # 2|BA||BC| sin(B + 60°)
    den_c = cross + _SQRT3 * (acx * bcx + acy * bcy)  # 2|CA||CB| sin(C + 60°)
    if den_a <= 0.0:
        return ax, ay, 0
    if den_b <= 0.0:
        return bx, by, 1
    if den_c <= 0.0:
        return cx, cy, 2
    # Barycentric weights 1/den_a : 1/den_b : 1/den_c, written as products (no overflow).
    wa, wb, wc = den_b * den_c, den_a * den_c, den_a * den_b
    total = wa + wb + wc
    wb, wc = wb / total, wc / total
    return ax + scale * (wb * abx + wc * acx), ay + scale * (wb * aby + wc * acy), -1


def fermat_point(a_m: npt.ArrayLike, b_m: npt.ArrayLike, c_m: npt.ArrayLike) -> np.ndarray:
    """Fermat point (geometric median) of one triangle.

    Parameters
    ----------
    a_m, b_m, c_m : (2,) float64, metres
        The triangle's vertices.

    Returns
    -------
    (2,) float64, metres
        The point minimising ``|x-a| + |x-b| + |x-c|``: the vertex whose angle is ≥ 120° if there
        is one (also when two vertices coincide or all three are collinear), else the interior
        point seeing every side under 120°. See :func:`fermat_points` for the formula.
    """
    a = np.asarray(a_m, dtype=np.float64)
    b = np.asarray(b_m, dtype=np.float64)
    c = np.asarray(c_m, dtype=np.float64)
    for name, v in (("a_m", a), ("b_m", b), ("c_m", c)):
        if v.shape != (2,):
            raise ValueError(f"{name} must be (2,) float64 metres, got shape {v.shape}")
    x, y, _ = _fermat_scalar(a[0], a[1], b[0], b[1], c[0], c[1])
    return np.array([x, y], dtype=np.float64)


def _fermat_complex(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, exact_ab: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised Fermat points of triangles given as complex arrays ``x + 1j*y`` (broadcastable).

    Returns ``(z, at_a, at_b, at_c)``. ``at_X`` marks triangles whose angle at X is ≥ 120° (or X
    coincides with another vertex); there z is a bit-exact copy of that vertex, with priority
    a > b > c. Elsewhere z is the interior Fermat point. With ``exact_ab=False`` z is left
    unspecified (finite) where ``at_a | at_b``, for callers that discard those triangles.

    Complex numbers are only a compact 2-D vector notation here (``conj(u) * v`` has real part
    u·v), which saves NumPy calls in this hot kernel: the greedy build calls it once per insertion.
    """
    ab, ac = b - a, c - a
    # Work in units of the longest side at a, so the weights cannot overflow or underflow.
    # (Clamped at the smallest normal float so that 1/scale is finite; all-zero triangles then give
    # den_a = 0 and return a.)
    scale = np.maximum(np.maximum(np.abs(ab), np.abs(ac)), _TINY)
    inv_scale = 1.0 / scale
    ab, ac, bc = ab * inv_scale, ac * inv_scale, (c - b) * inv_scale
    # Twice the area, from real products in separate calls: exactly 0 whenever two vertices
    # coincide (a fused complex multiply may leave a rounding residue there).
    cross = np.abs(ab.real * ac.imag - ab.imag * ac.real)
    den_a = cross + _SQRT3 * (ab.conjugate() * ac).real  # 2|AB||AC| sin(A + 60°)
    den_b = cross - _SQRT3 * (ab.conjugate() * bc).real  # 2|BA||BC| sin(B + 60°)
    den_c = cross + _SQRT3 * (ac.conjugate() * bc).real  # 2|CA||CB| sin(C + 60°)
    at_a, at_b, at_c = den_a <= 0.0, den_b <= 0.0, den_c <= 0.0
    # Barycentric weights 1/den_a : 1/den_b : 1/den_c, written as products so that a tiny den
    # (near-coincident vertices) cannot overflow. A non-positive den (vertex answer, overwritten
    # below) is replaced by 1 so that the weights stay positive: no warnings, no 0/0.
    den_a = np.where(at_a, 1.0, den_a)
    den_b = np.where(at_b, 1.0, den_b)
    den_c = np.where(at_c, 1.0, den_c)
    wa, wb, wc = den_b * den_c, den_a * den_c, den_a * den_b
    total = wa + wb + wc  # > 0, possibly subnormal
    z = a + scale * ((wb / total) * ab + (wc / total) * ac)
    z = np.where(at_c, c, z)
    if exact_ab:
        z = np.where(at_a, a, np.where(at_b, b, z))
    return z, at_a, at_b, at_c


def _as_complex(xy_m: np.ndarray) -> np.ndarray:
    """(..., 2) float64 -> (...) complex128 ``x + 1j*y``."""
    return xy_m[..., 0] + 1j * xy_m[..., 1]


def fermat_points(a_m: npt.ArrayLike, b_m: npt.ArrayLike, c_m: npt.ArrayLike) -> np.ndarray:
    """Vectorised Fermat points of P triangles (closed form, exact up to rounding).

    Parameters
    ----------
    a_m, b_m, c_m : (P, 2) float64, metres
        Vertices of each triangle (rows broadcast against each other).

    Returns
    -------
    (P, 2) float64, metres
        The geometric median of each vertex triple.

    Notes
    -----
    With ``den_X = |AB × AC| + √3 (Y-X)·(Z-X) = 2|XY||XZ| sin(X + 60°)`` for vertex X and the other
    two vertices Y, Z: if ``den_X <= 0`` the angle at X is ≥ 120° and the median is X. The same test
    catches coincident vertices (both terms 0) and collinear triples (the middle vertex has 180°).
    Otherwise the Fermat point has barycentric coordinates ``a / sin(A + 60°) : b / sin(B + 60°) :
    c / sin(C + 60°)`` (Kimberling X(13)); multiplied by ``2abc`` these are ``1/den_A : 1/den_B :
    1/den_C``, all positive, with no trigonometry, and are evaluated as ``den_B·den_C : den_A·den_C
    : den_A·den_B``. Deciding the vertex case on the very numbers used as weights keeps the two
    branches consistent at exactly 120°. The computation runs relative to vertex A and in units
    of A's longest side, so it is translation-invariant to rounding and cannot overflow.

    Complexity O(P).
    """
    a = np.asarray(a_m, dtype=np.float64)
    b = np.asarray(b_m, dtype=np.float64)
    c = np.asarray(c_m, dtype=np.float64)
    a, b, c = np.broadcast_arrays(a, b, c)
    if a.ndim != 2 or a.shape[1] != 2:
        raise ValueError(f"a_m, b_m, c_m must broadcast to (P, 2) float64 metres, got {a.shape}")
    z = _fermat_complex(_as_complex(a), _as_complex(b), _as_complex(c))[0]
    return np.stack([z.real, z.imag], axis=1)


def fermat_point_reference(
    a_m: npt.ArrayLike, b_m: npt.ArrayLike, c_m: npt.ArrayLike
) -> np.ndarray:
    """Slow check of :func:`fermat_point` by direct minimisation (for tests).

    Minimises ``|x-a| + |x-b| + |x-c|`` with Nelder-Mead from the centroid at tight tolerances,
    then returns whichever of that result and the three vertices has the smallest objective (the
    objective is not differentiable at the vertices, where the optimum often sits).
    """
    pts = np.array([a_m, b_m, c_m], dtype=np.float64)

    def objective(x: np.ndarray) -> float:
        return float(np.sum(np.sqrt(np.sum((pts - x) ** 2, axis=1))))

    scale = max(1.0, float(np.max(np.abs(pts - pts.mean(axis=0)))))
    res = minimize(
        objective,
        pts.mean(axis=0),
        method="Nelder-Mead",
        options={
            "xatol": 1e-13 * scale,
            "fatol": 1e-15 * scale,
            "maxiter": 20000,
            "maxfev": 40000,
            "initial_simplex": pts.mean(axis=0)
            + scale * np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]]),
        },
    )
    candidates = [res.x, *pts]
    values = [objective(x) for x in candidates]
    return np.array(candidates[int(np.argmin(values))], dtype=np.float64)


def _geometric_median_scalar(
    xs: list[float], ys: list[float], x0: float, y0: float
) -> tuple[float, float, int]:
    """Geometric median of a few points (Weiszfeld from ``(x0, y0)``): ``(x, y, vertex)``.

    ``vertex`` is the index of an input point that is itself the median (``|Σ unit vectors from it
    to the other points| <= its multiplicity``), else -1. Weiszfeld is a majorise-minimise scheme,
    so started off the inputs it never increases the objective.
    """
    n = len(xs)
    for j in range(n):
        rx = ry = 0.0
        mult = 0
        for i in range(n):
            dx, dy = xs[i] - xs[j], ys[i] - ys[j]
            d = math.hypot(dx, dy)
            if d == 0.0:
                mult += 1
            else:
                rx += dx / d
                ry += dy / d
        if math.hypot(rx, ry) <= mult:
            return xs[j], ys[j], j
    x, y = x0, y0
    if any(x == xs[i] and y == ys[i] for i in range(n)):
        x, y = sum(xs) / n, sum(ys) / n
    scale = max(math.hypot(xs[i] - x, ys[i] - y) for i in range(n))
    for _ in range(_WEISZFELD_MAX_ITER):
        sw = sx = sy = 0.0
        for i in range(n):
            d = math.hypot(xs[i] - x, ys[i] - y)
            if d == 0.0:  # landed on an input point that is not the median: stop here
                return x, y, -1
            sw += 1.0 / d
            sx += xs[i] / d
            sy += ys[i] / d
        nx, ny = sx / sw, sy / sw
        step = math.hypot(nx - x, ny - y)
        x, y = nx, ny
        if step <= 1e-14 * scale:
            break
    return x, y, -1


# --------------------------------------------------------------------------------------------
# Cost
# --------------------------------------------------------------------------------------------


def tree_cost(tree: TaskTree, base_weight: float = 1.0) -> tuple[float, float, float]:
    """The paper's tree cost l_Σ and its two parts.

    Parameters
    ----------
    tree : TaskTree
    base_weight : float
        c_b ≥ 0, the weight of the task-to-base path lengths.

    Returns
    -------
    l_total_m : float
        ``l_edges_m + base_weight * l_base_m`` (metres).
    l_edges_m : float
        l_Σe, the total edge length, metres.
    l_base_m : float
        l_Σb, the sum over tasks (not Steiner nodes) of the tree-path length to the base, metres.
    """
    edge_len = tree.edge_lengths_m()
    path = _root_path_lengths(tree.parent, edge_len)
    l_edges = float(edge_len.sum())
    l_base = float(path[1 : 1 + tree.n_tasks].sum())
    return l_edges + float(base_weight) * l_base, l_edges, l_base


# --------------------------------------------------------------------------------------------
# Greedy construction
# --------------------------------------------------------------------------------------------


def _check_inputs(
    base_m: npt.ArrayLike, task_pos_m: npt.ArrayLike, base_weight: float
) -> tuple[np.ndarray, np.ndarray, float]:
    base = np.asarray(base_m, dtype=np.float64)
    tasks = np.asarray(task_pos_m, dtype=np.float64)
    if base.shape != (2,) or not np.all(np.isfinite(base)):
        raise ValueError(f"base_m must be finite (2,) float64 metres, got shape {base.shape}")
    if tasks.ndim != 2 or tasks.shape[1] != 2 or not np.all(np.isfinite(tasks)):
        raise ValueError(
            f"task_pos_m must be finite (M, 2) float64 metres, got shape {tasks.shape}"
        )
    cb = float(base_weight)
    if not (math.isfinite(cb) and cb >= 0.0):
        raise ValueError(f"base_weight (c_b) must be finite and >= 0, got {base_weight}")
    return base, tasks, cb


def _direct_costs(y: np.ndarray, p: np.ndarray, cb: float) -> np.ndarray:
    """(F, n) option (a) costs (1 + c_b)|y - p| of the free tasks y (F, 1) to the nodes p (n,)."""
    return (1.0 + cb) * np.abs(y - p)


def _split_costs(
    u: np.ndarray, w: np.ndarray, y: np.ndarray, n_below: np.ndarray, cb: float
) -> tuple[np.ndarray, np.ndarray]:
    """(F, n) ``(split, stretch)`` of the edges u -> w (n,) for the free tasks y (F, 1), with
    ``n_below`` (n,) tasks below each edge; see :func:`_greedy_tree_python`."""
    s, at_u, at_w, _ = _fermat_complex(u, w, y, exact_ab=False)  # (F, n) triangles (u, w, y)
    us, sy = np.abs(s - u), np.abs(y - s)
    detour = us + np.abs(w - s) - np.abs(w - u)
    cost = (detour + sy) + cb * ((us + sy) + n_below * detour)
    # s at u or w is just a direct edge, which option (a) already prices identically.
    return np.where(at_u | at_w, np.inf, cost), cb * detour


def _greedy_tree(base: np.ndarray, tasks: np.ndarray, cb: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_greedy_tree_python`, compiled when Numba is there and NumPy on this machine
    evaluates as the kernel emulates (:func:`planner._greedy_kernels.greedy_tree`: the same
    bits)."""
    fast = _greedy_kernels.greedy_tree(base, tasks, cb, _GREEDY_REFERENCE)
    if fast is not None:
        return fast
    return _greedy_tree_python(base, tasks, cb)


def _greedy_tree_python(
    base: np.ndarray, tasks: np.ndarray, cb: float
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy semi-Steiner insertion; returns ``(nodes_m, parent)`` in :class:`TaskTree` order.

    Layout, chosen so that each step is a handful of NumPy calls on contiguous blocks:

    * nodes are numbered internally in creation order (0 = B), so the live columns are ``[:n]``;
      they are renumbered into TaskTree order at the end;
    * the unattached tasks occupy the first ``n_free`` rows (``row_task`` maps row -> task);
      attaching one swaps its row with the last free one;
    * positions are complex ``x + 1j*y``.

    Cached per (free task row, node or edge column):

    * ``direct[j, v]`` = (1 + c_b)|y - v|  -> option (a) cost ``direct + c_b·path(v)``;
    * per edge, indexed by its child node c (edge = (u = parent[c], w = c)), the split at
      s = Fermat(u, w, y), with geo = |u-s|+|s-w|+|s-y|-|u-w|, detour = |u-s|+|s-w|-|u-w| and
      leg = |u-s|+|s-y|: ``stretch[j, c]`` = c_b·detour and
      ``split[j, c]`` = geo + c_b·leg + n_below(c)·stretch (inf where s is u or w)
      -> option (b) cost ``split + c_b·path(u)``.

    ``path`` (length to B), ``n_below`` (tasks in the subtree) and ``anc[v, a]`` (a is v or an
    ancestor of v) are updated incrementally, and ``split`` with them. An insertion changes at most
    three edges, so only those columns get new Fermat points: O(m·K) array work per step, O(m²·K)
    in all.
    """
    m = len(tasks)
    kmax = 2 * m + 1
    task_z = _as_complex(tasks)
    row_z = task_z.copy()  # free tasks first
    row_task = np.arange(m)
    pos = np.zeros(kmax, dtype=np.complex128)
    pos[0] = complex(base[0], base[1])
    final_index = np.zeros(kmax, dtype=np.int64)  # internal (creation order) -> TaskTree order
    parent = np.zeros(kmax, dtype=np.int64)  # parent[0] = 0 here; -1 in the output
    path = np.zeros(kmax)
    n_below = np.zeros(kmax)
    anc = np.zeros((kmax, kmax), dtype=bool)
    anc[0, 0] = True
    # One block, so that retiring a task swaps a row of all three tables in one call.
    tables = np.stack([np.full((m, kmax), np.inf), np.full((m, kmax), np.inf), np.zeros((m, kmax))])
    direct, split, stretch = tables  # views; split column 0 (B) stays inf

    def add_node_columns(vs: list[int], n_free: int) -> None:
        # (F, 1) free tasks - (n,) new nodes -> (F, n)
        direct[:n_free, vs] = _direct_costs(row_z[:n_free, None], pos[vs], cb)

    def add_edge_columns(cs: list[int], n_free: int) -> None:
        # (n,) edge tops and bottoms, (F, 1) free tasks -> (F, n)
        split[:n_free, cs], stretch[:n_free, cs] = _split_costs(
            pos[parent[cs]], pos[cs], row_z[:n_free, None], n_below[cs], cb
        )

    def new_node(z: complex, final: int, under: int) -> int:
        """Create a leaf at ``z`` under node ``under``; return its internal index."""
        v = n_nodes[0]
        n_nodes[0] += 1
        pos[v] = z
        final_index[v] = final
        parent[v] = under
        path[v] = path[under] + abs(z - pos[under])
        anc[v] = anc[under]
        anc[v, v] = True
        return v

    def lift_onto(v: int, w: int) -> None:
        """Make the new leaf v (a child of w's parent u) the parent of w: u -> v -> w."""
        u = parent[w]
        parent[w] = v
        extra = abs(pos[v] - pos[u]) + abs(pos[w] - pos[v]) - abs(pos[w] - pos[u])
        below = anc[:, w]
        path[below] += extra
        anc[below, v] = True
        n_below[v] = n_below[w]

    n_nodes = [1]
    n_steiner = 0
    add_node_columns([0], m)
    for n_free in range(m, 0, -1):
        n = n_nodes[0]
        if _kernels.NUMBA and _kernels.ENABLED:
            # the lines below without forming the (F, n) cost arrays, the same sums and first minima
            ia, a_min, ib, b_min = _kernels.greedy_pick(
                direct, split, cb * path if cb != 0.0 else path, parent, n_free, n, cb != 0.0
            )
            use_direct = a_min <= b_min
        else:
            if cb == 0.0:
                cost_a = direct[:n_free, :n]
                cost_b = split[:n_free, :n]
            else:
                cb_path = cb * path[:n]
                cost_a = direct[:n_free, :n] + cb_path  # (a), (F, n)
                cost_b = split[:n_free, :n] + cb_path[parent[:n]]  # (b); column 0 (B) is inf
            ia = int(np.argmin(cost_a))
            ib = int(np.argmin(cost_b))
            use_direct = cost_a.flat[ia] <= cost_b.flat[ib]
        j, col = divmod(ia if use_direct else ib, n)
        k = int(row_task[j])
        y = complex(task_z[k])
        if not use_direct:
            c, u = col, int(parent[col])
            sx, sy, vertex = _fermat_scalar(
                pos[u].real, pos[u].imag, pos[c].real, pos[c].imag, y.real, y.imag
            )
            if vertex in (0, 1):  # rounding put s on u or w after all: a direct edge
                use_direct, col = True, (u if vertex == 0 else c)
        if use_direct:
            node = new_node(y, 1 + k, col)
            new_nodes, new_edges = [node], [node]
        elif vertex == 2:
            # s = y (angle >= 120° at the task): the task itself goes on the edge u -> y -> w.
            node = new_node(y, 1 + k, u)
            lift_onto(node, c)
            new_nodes, new_edges = [node], [node, c]
        else:
            steiner = new_node(complex(sx, sy), m + 1 + n_steiner, u)
            n_steiner += 1
            lift_onto(steiner, c)
            node = new_node(y, 1 + k, steiner)
            new_nodes, new_edges = [steiner, node], [steiner, c, node]
        # One more task below each ancestor of the new task: their split costs grow by c_b·detour.
        above = np.flatnonzero(anc[node])
        n_below[above] += 1.0
        if cb != 0.0:
            split[:, above] += stretch[:, above]
        # Retire row j: swap it with the last free row.
        last = n_free - 1
        if j != last:
            tables[:, [j, last]] = tables[:, [last, j]]
            row_z[[j, last]] = row_z[[last, j]]
            row_task[[j, last]] = row_task[[last, j]]
        if last:
            add_node_columns(new_nodes, last)
            add_edge_columns(new_edges, last)

    n = n_nodes[0]
    nodes_out = np.empty((n, 2))
    nodes_out[final_index[:n], 0] = pos[:n].real
    nodes_out[final_index[:n], 1] = pos[:n].imag
    parent_out = np.full(n, -1, dtype=np.int64)
    parent_out[final_index[1:n]] = final_index[parent[1:n]]
    return nodes_out, parent_out


#: What :func:`planner._greedy_kernels.greedy_tree` reproduces (and checks itself against).
_GREEDY_REFERENCE = _greedy_kernels.Reference(
    _as_complex, _direct_costs, _split_costs, _fermat_scalar
)


# --------------------------------------------------------------------------------------------
# Fermat relaxation of the Steiner nodes (shared by the build and the per-tick update)
# --------------------------------------------------------------------------------------------


#: False: every sweep runs and every tick relaxes (the reference the tests compare the shortcuts
#: of :func:`_relax_steiner` and :func:`update_task_positions` against).
RELAX_SHORTCUTS = True

#: Attribute set on a tree returned by :func:`update_task_positions` whose last sweep changed
#: nothing (not a dataclass field: equality and repr ignore it).
_RELAXED = "_relaxed_fixed_point"


def _same_bits(a: float, b: float) -> bool:
    """a and b are the same float, bit for bit (0.0 and -0.0 differ; a NaN is never the same)."""
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


def _relax_steiner(
    nodes_m: np.ndarray, parent: np.ndarray, n_tasks: int, sweeps: int
) -> tuple[np.ndarray, np.ndarray, bool]:
    """:func:`_relax_steiner_python`, compiled when Numba is there
    (:func:`planner._steiner_kernels.relax_steiner`: the same bits, the same fixed-point flag)."""
    fast = _steiner_kernels.relax_steiner(
        nodes_m, parent, n_tasks, sweeps, RELAX_SHORTCUTS, _COINCIDE_RTOL, _WEISZFELD_MAX_ITER
    )
    if fast is not None:
        return fast
    return _relax_steiner_python(nodes_m, parent, n_tasks, sweeps)


def _relax_steiner_python(
    nodes_m: np.ndarray, parent: np.ndarray, n_tasks: int, sweeps: int
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Gauss-Seidel sweeps over the Steiner nodes; splices degenerate ones; compacts indices.
    Returns the nodes, the parents and whether nothing was spliced and the last sweep run changed
    nothing (the tree is then a fixed point: relaxing it again with the same tasks returns it).

    In index order, each live Steiner node s with neighbours N(s) (parent + children):

    * |N(s)| <= 2: spliced out (its child, if any, attaches to its parent); l_Σe cannot grow.
    * |N(s)| == 3: moved to the Fermat point of N(s); if that is a neighbour (angle ≥ 120°), s is
      spliced onto that neighbour.
    * |N(s)| >= 4: the same with the geometric median (Weiszfeld from s's current position).

    A move is kept only if it does not lengthen s's incident edges, so l_Σe never increases.
    Splicing onto a neighbour v: if v is s's parent, s's children attach to it; if v is a child,
    v takes s's place under s's parent and s's other children attach to v (tree paths through s
    keep their length, since s sat on v).
    """
    k_nodes = len(nodes_m)
    xs = nodes_m[:, 0].tolist()
    ys = nodes_m[:, 1].tolist()
    par = parent.tolist()
    children: list[list[int]] = [[] for _ in range(k_nodes)]
    for v in range(1, k_nodes):
        children[par[v]].append(v)
    alive = [True] * k_nodes

    spliced = False  # any splice in this call (children lists then leave index order)

    def splice(s: int, onto: int) -> None:
        nonlocal spliced
        spliced = True
        p = par[s]
        children[p].remove(s)
        if onto == p:
            for c in children[s]:
                par[c] = p
                children[p].append(c)
        else:
            par[onto] = p
            children[p].append(onto)
            for c in children[s]:
                if c != onto:
                    par[c] = onto
                    children[onto].append(c)
        children[s] = []
        alive[s] = False

    changed = True
    for _ in range(sweeps):
        # A sweep that changes nothing (no splice, no coordinate's bits) leaves the state as it
        # was, so every later sweep would repeat it exactly: stop there (the same result).
        changed = False
        for s in range(n_tasks + 1, k_nodes):
            if not alive[s]:
                continue
            nbrs = [par[s], *children[s]]
            if len(nbrs) <= 2:
                splice(s, par[s])
                changed = True
                continue
            nx = [xs[v] for v in nbrs]
            ny = [ys[v] for v in nbrs]
            if len(nbrs) == 3:
                x, y, vert = _fermat_scalar(nx[0], ny[0], nx[1], ny[1], nx[2], ny[2])
            else:
                x, y, vert = _geometric_median_scalar(nx, ny, xs[s], ys[s])
            if vert >= 0:
                splice(s, nbrs[vert])
                changed = True
                continue
            old = sum(math.hypot(nx[i] - xs[s], ny[i] - ys[s]) for i in range(len(nbrs)))
            dists = [math.hypot(nx[i] - x, ny[i] - y) for i in range(len(nbrs))]
            if sum(dists) <= old:
                if not changed and not (_same_bits(x, xs[s]) and _same_bits(y, ys[s])):
                    changed = True
                xs[s], ys[s] = x, y
            else:
                dists = [math.hypot(nx[i] - xs[s], ny[i] - ys[s]) for i in range(len(nbrs))]
            j = min(range(len(nbrs)), key=dists.__getitem__)
            if dists[j] <= _COINCIDE_RTOL * (1.0 + max(dists)):
                splice(s, nbrs[j])
                changed = True
        if not changed and RELAX_SHORTCUTS:
            break

    # Relaxing the returned tree again rebuilds the children lists in index order; that is this
    # call's order only if nothing was spliced (a splice appends children out of order).
    fixed = sweeps > 0 and not changed and not spliced
    keep = np.array([v for v in range(k_nodes) if alive[v]], dtype=np.int64)
    new_index = np.full(k_nodes, -1, dtype=np.int64)
    new_index[keep] = np.arange(len(keep))
    par_arr = np.array(par, dtype=np.int64)[keep]
    new_parent = np.where(par_arr < 0, -1, new_index[np.maximum(par_arr, 0)])
    new_nodes = np.stack([np.array(xs)[keep], np.array(ys)[keep]], axis=1)
    return new_nodes, new_parent, fixed


# --------------------------------------------------------------------------------------------
# Public construction / maintenance
# --------------------------------------------------------------------------------------------


def build_task_tree(
    base_m: npt.ArrayLike,
    task_pos_m: npt.ArrayLike,
    base_weight: float = 1.0,
    refine_sweeps: int = 3,
) -> TaskTree:
    """Build a semi-Steiner task tree greedily (docs/design/model.md §5.3).

    Parameters
    ----------
    base_m : (2,) float64, metres
        Base-station position B (the root).
    task_pos_m : (M, 2) float64, metres
        Task positions y_k, in task order.
    base_weight : float
        c_b ≥ 0 in l_Σ = l_Σe + c_b·l_Σb (paper default 1.0).
    refine_sweeps : int
        Gauss-Seidel Fermat sweeps after the greedy pass (0 = none).

    Returns
    -------
    TaskTree
        Spans B and every task; Steiner nodes have degree ≥ 3.

    Notes
    -----
    The paper only says the tree is built greedily, "inserting auxiliary Steiner nodes to reduce
    overall distance costs". The procedure here is our reconstruction [inference], a Prim-like
    insertion rooted at B. Starting from {B}, each step takes, over every unattached task k, the
    cheapest of:

    (a) a direct edge to an existing node u (B, task or Steiner node), with cost increase
        ``Δ = |y_k-u| + c_b·(|y_k-u| + path(u))``;
    (b) splitting an existing edge (u parent, w child) at s = Fermat(u, w, y_k), with
        ``Δ = (|u-s|+|s-w|+|s-y_k|-|u-w|)
        + c_b·(n(w)·(|u-s|+|s-w|-|u-w|) + path(u) + |u-s| + |s-y_k|)``,

    where path(u) is the tree-path length from u to B and n(w) the number of tasks below w. If s
    is u or w (an angle ≥ 120° there) the split is just option (a). If s is y_k the task itself is
    inserted on the edge, with no Steiner node. Each Δ is the exact change of l_Σ, and option (a)
    to B is always available, so the greedy tree never costs more than the star (every task
    straight to B).

    The split point is the unweighted Fermat point, as the paper prescribes for Steiner nodes.
    For c_b > 0 the cost-optimal point would be a weighted one, so a refinement sweep can raise
    l_Σ while lowering l_Σe. The refined tree is returned unless its l_Σ exceeds the greedy
    tree's. Either way, l_Σ never exceeds the star's.

    Ties go to option (a), then to the task that comes first in an internal swap-remove order, then
    to the earliest-created node (or edge), so the result is deterministic.

    Complexity: O(m·K) array work per insertion (K ≤ 2m + 1 nodes), O(m²·K) in all, plus
    O(sweeps·K) scalar work for the refinement.
    """
    base, tasks, cb = _check_inputs(base_m, task_pos_m, base_weight)
    m = len(tasks)
    if m == 0:
        return TaskTree(base[None, :], np.array([-1], dtype=np.int64), 0)
    nodes, parent = _greedy_tree(base, tasks, cb)
    greedy = TaskTree(nodes, parent, m)
    if refine_sweeps <= 0:
        return greedy
    refined = TaskTree(*_relax_steiner(nodes, parent, m, int(refine_sweeps))[:2], m)
    if tree_cost(refined, cb)[0] <= tree_cost(greedy, cb)[0]:
        return refined
    return greedy


def update_task_positions(tree: TaskTree, task_pos_m: npt.ArrayLike, sweeps: int = 3) -> TaskTree:
    """Move the task nodes, keep the topology, and relax the Steiner nodes to Fermat points.

    Parameters
    ----------
    tree : TaskTree
    task_pos_m : (n_tasks, 2) float64, metres
        New task positions, in task order.
    sweeps : int
        Gauss-Seidel sweeps. In each, every Steiner node moves to the Fermat point of its three
        neighbours (parent + children), or to their geometric median if it has more. A Steiner node
        whose Fermat point is a neighbour (angle ≥ 120°) is spliced onto it, and one with fewer
        than three neighbours is spliced out. Remaining Steiner nodes are renumbered in order.

    Returns
    -------
    TaskTree
        Same base and task nodes. With the tasks held fixed, l_Σe never increases (up to
        rounding), since each move and each splice can only shorten edges.
    """
    tasks = np.asarray(task_pos_m, dtype=np.float64)
    if tasks.shape != (tree.n_tasks, 2) or not np.all(np.isfinite(tasks)):
        raise ValueError(
            f"task_pos_m must be finite ({tree.n_tasks}, 2) float64 metres, got shape {tasks.shape}"
        )
    if sweeps < 0:
        raise ValueError(f"sweeps must be >= 0, got {sweeps}")
    if (
        RELAX_SHORTCUTS
        and sweeps > 0
        and getattr(tree, _RELAXED, False)
        and np.array_equal(tree.nodes_m[1 : 1 + tree.n_tasks].view(np.int64), tasks.view(np.int64))
    ):
        # The tree is a fixed point of a sweep and its tasks have the same bits: the sweeps below
        # would change nothing (no move, no splice, the indices already compact). Trees are
        # immutable, so the same one is returned.
        return tree
    nodes = np.array(tree.nodes_m)
    nodes[1 : 1 + tree.n_tasks] = tasks
    nodes, parent, fixed = _relax_steiner(nodes, np.array(tree.parent), tree.n_tasks, int(sweeps))
    out = TaskTree(nodes, parent, tree.n_tasks)
    if fixed:
        object.__setattr__(out, _RELAXED, True)
    return out


def maintain_task_tree(
    tree: TaskTree | None,
    base_m: npt.ArrayLike,
    task_pos_m: npt.ArrayLike,
    t_step: int,
    base_weight: float = 1.0,
    accept_ratio: float = 0.99,
    rebuild_period: int = 10,
    sweeps: int = 3,
) -> TaskTree:
    """The per-tick tree policy of PhiIREMAN (docs/design/model.md §5.3, §7 #10).

    Parameters
    ----------
    tree : TaskTree or None
        The current tree. None builds one from scratch. So does a task count that differs from
        ``tree.n_tasks``.
    base_m : (2,) float64, metres
        Base position. The root node is moved there if it has changed.
    task_pos_m : (M, 2) float64, metres
        Current task positions.
    t_step : int
        Tick index. A rebuild is tried when ``t_step % rebuild_period == 0``.
    base_weight : float
        c_b.
    accept_ratio : float
        ν > 0. A rebuilt tree replaces the current one only if ``l_Σ^new < ν·l_Σ^curr``, with both
        costs taken at the current positions (paper default 0.99).
    rebuild_period : int
        Ticks between rebuild attempts (≥ 1). 0 disables rebuilds.
    sweeps : int
        Fermat sweeps of :func:`update_task_positions` per tick.

    Returns
    -------
    TaskTree
        Every tick, the current tree with its tasks moved and its Steiner nodes relaxed. On
        rebuild ticks, the fresh greedy tree instead if it passes the ν rule.
    """
    base, tasks, cb = _check_inputs(base_m, task_pos_m, base_weight)
    if not accept_ratio > 0.0:
        raise ValueError(f"accept_ratio (nu) must be > 0, got {accept_ratio}")
    if rebuild_period < 0:
        raise ValueError(f"rebuild_period must be >= 0 ticks, got {rebuild_period}")
    if tree is None or tree.n_tasks != len(tasks):
        return build_task_tree(base, tasks, cb)
    if not np.array_equal(tree.nodes_m[0], base):
        nodes = np.array(tree.nodes_m)
        nodes[0] = base
        tree = TaskTree(nodes, tree.parent, tree.n_tasks)
    current = update_task_positions(tree, tasks, sweeps)
    if rebuild_period > 0 and t_step % rebuild_period == 0:
        fresh = build_task_tree(base, tasks, cb)
        if tree_cost(fresh, cb)[0] < accept_ratio * tree_cost(current, cb)[0]:
            return fresh
    return current


# --------------------------------------------------------------------------------------------
# Distance to the tree: h^T(x)
# --------------------------------------------------------------------------------------------


def _check_points(points_m: npt.ArrayLike) -> np.ndarray:
    pts = np.asarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"points_m must be (P, 2) float64 metres, got shape {pts.shape}")
    return pts


def distance_to_tree(
    points_m: npt.ArrayLike, tree: TaskTree, nodes_only: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each point to the task tree, and the nearest point on it.

    Parameters
    ----------
    points_m : (P, 2) float64, metres
        Query points (drone positions).
    tree : TaskTree
    nodes_only : bool
        False: the tree is the union of its edge segments (the paper's h^T). True: only its nodes
        count (the "nodes only" ablation). A tree with one node (no tasks) is that node.

    Returns
    -------
    dist_m : (P,) float64, metres
    nearest_m : (P, 2) float64, metres
        The nearest tree point p*, an exact clamped projection onto the nearest segment, so that
        ``(x - p*) / |x - p*|`` is the gradient of h^T at x (where x is off the tree). Ties go to
        the lowest edge (node) index.

    Notes
    -----
    (P, E) broadcasting, O(P·K) time and memory.
    """
    pts = _check_points(points_m)
    if nodes_only or tree.n_nodes == 1:
        diff = pts[:, None, :] - tree.nodes_m[None, :, :]  # (P,1,2) - (1,K,2) -> (P,K,2)
        d2 = np.einsum("pkd,pkd->pk", diff, diff)
        nearest = tree.nodes_m[np.argmin(d2, axis=1)] if len(pts) else np.empty((0, 2))
    else:
        a_m, b_m = tree.segments()  # (E,2) child end, parent end
        ab = b_m - a_m
        ab2 = np.einsum("ed,ed->e", ab, ab)
        ap = pts[:, None, :] - a_m[None, :, :]  # (P,1,2) - (1,E,2) -> (P,E,2)
        # Zero-length edges project to their end; near-zero ones may overflow to ±inf, which the
        # clamp turns into the right end.
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.where(ab2 > 0.0, np.einsum("ped,ed->pe", ap, ab) / ab2, 0.0)
        t = np.clip(t, 0.0, 1.0)
        foot = a_m[None, :, :] + t[:, :, None] * ab[None, :, :]  # (P,E,2)
        off = pts[:, None, :] - foot
        d2 = np.einsum("ped,ped->pe", off, off)
        best = np.argmin(d2, axis=1) if len(pts) else np.empty(0, dtype=np.int64)
        nearest = foot[np.arange(len(pts)), best]
    delta = pts - nearest
    return np.sqrt(np.einsum("pd,pd->p", delta, delta)), nearest


def distance_to_tree_reference(
    points_m: npt.ArrayLike, tree: TaskTree, nodes_only: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Plain-loop version of :func:`distance_to_tree` (for tests)."""
    pts = _check_points(points_m)
    nodes = [(float(x), float(y)) for x, y in tree.nodes_m]
    dist = np.zeros(len(pts))
    nearest = np.zeros((len(pts), 2))
    for i, (px, py) in enumerate(pts.tolist()):
        best = (math.inf, 0.0, 0.0)
        if nodes_only or tree.n_nodes == 1:
            for x, y in nodes:
                d = math.hypot(px - x, py - y)
                if d < best[0]:
                    best = (d, x, y)
        else:
            for child in range(1, tree.n_nodes):
                ax, ay = nodes[child]
                bx, by = nodes[int(tree.parent[child])]
                ex, ey = bx - ax, by - ay
                length2 = ex * ex + ey * ey
                t = 0.0 if length2 == 0.0 else ((px - ax) * ex + (py - ay) * ey) / length2
                t = min(1.0, max(0.0, t))
                fx, fy = ax + t * ex, ay + t * ey
                d = math.hypot(px - fx, py - fy)
                if d < best[0]:
                    best = (d, fx, fy)
        dist[i], nearest[i] = best[0], best[1:]
    return dist, nearest
