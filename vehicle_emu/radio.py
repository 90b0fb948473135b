"""Who hears the ground station: the emulator is the radio (a disk model over a mesh).

A vehicle's traffic reaches the GCS, and the GCS's reaches it, only while the vehicle is
*active*: connected to the base (a radio node at the swarm home) through a chain of alive
vehicles, each hop no longer than ``radio_range_m`` (the paper's a_i). The definition is
:func:`planner.geometry.active_mask`, shared with the planner and the metrics, so "networked"
means the same everywhere.

Optional per-hop latency and per-hop loss probability (seeded through an injected
``numpy.random.Generator``) model a multi-hop mesh: a packet from a vehicle h hops from the
base is delayed by ``h * latency_per_hop_s`` and survives with probability
``(1 - loss_per_hop) ** h``. Hop counts are breadth-first distances in the same graph.

Distances are horizontal (north/east) by default, like the paper's 2-D model; ``planar=False``
uses 3-D distances.

Over terrain (a mission's ``radio.model: terrain``) the radio is given the mission's
:class:`vehicle_emu.terrain.Ground`: a hop then exists when its link clears the terrain and closes
its budget (:meth:`planner.terrain.TerrainRadio.active_mask`, the in-process world's model), and
the range settings are not used (docs/terrain.md §5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order

from planner.geometry import active_mask, neighbour_pairs

from . import _kernels
from .terrain import Ground

__all__ = ["RadioConfig", "Radio"]


@dataclass(frozen=True)
class RadioConfig:
    """Radio model parameters."""

    radio_range_m: float = math.inf
    """Drone-drone range r, metres (``inf``: everybody hears the base)."""
    base_range_m: float | None = None
    """Drone-base range R, metres (``None``: same as ``radio_range_m``)."""
    latency_per_hop_s: float = 0.0
    """One-way delay added per hop, seconds."""
    loss_per_hop: float = 0.0
    """Probability that a packet is lost on one hop, in [0, 1)."""
    planar: bool = True
    """Use horizontal distances (the paper's 2-D model)."""

    def __post_init__(self) -> None:
        if not self.radio_range_m > 0:
            raise ValueError(f"radio_range_m must be > 0, got {self.radio_range_m}")
        if self.base_range_m is not None and not self.base_range_m > 0:
            raise ValueError(f"base_range_m must be > 0, got {self.base_range_m}")
        if self.latency_per_hop_s < 0:
            raise ValueError("latency_per_hop_s must be >= 0")
        if not 0 <= self.loss_per_hop < 1:
            raise ValueError("loss_per_hop must be in [0, 1)")


class Radio:
    """Connectivity state of the swarm, refreshed by :meth:`update`.

    Parameters
    ----------
    config : RadioConfig
    base_ned_m : (3,) float64
        Base station position, world NED metres (the swarm home: origin).
    rng : numpy.random.Generator
        Source of loss randomness.
    """

    def __init__(
        self,
        config: RadioConfig,
        base_ned_m,
        rng: np.random.Generator,
        ground: Ground | None = None,
    ) -> None:
        self._config = config
        #: Links over terrain (None: the disc of ``config``).
        self.ground = ground
        #: Hop counts are kept (latency or loss per hop); without them a packet's fate is
        #: just ``active`` (config is fixed at construction, so is this).
        self._needs_hops = config.latency_per_hop_s > 0 or config.loss_per_hop > 0
        self.base_ned_m = np.asarray(base_ned_m, dtype=float)
        self.rng = rng
        self.active = np.zeros(0, dtype=bool)
        """(N,) bool — vehicles that can exchange traffic with the GCS."""
        self.hops = np.zeros(0, dtype=np.int64)
        """(N,) int — hop count to the base (0 if inactive); only maintained with latency/loss."""
        self.n_dropped_inactive = 0
        self.n_dropped_loss = 0

    @property
    def config(self) -> RadioConfig:
        """The radio model (fixed at construction)."""
        return self._config

    def update(self, pos_ned_m: np.ndarray, alive: np.ndarray) -> np.ndarray:
        """Recompute ``active`` (and hop counts) from positions and the alive mask."""
        cfg = self.config
        pos = np.asarray(pos_ned_m, dtype=float)
        base = self.base_ned_m
        if self.ground is not None:
            self.active = self.ground.active_mask(pos, alive, base)
            if self._needs_hops:
                self.hops = self._hop_counts_terrain(pos, base)
            return self.active
        if cfg.planar:
            pos, base = pos[:, :2], base[:2]
        base_range = cfg.radio_range_m if cfg.base_range_m is None else cfg.base_range_m
        if math.isinf(cfg.radio_range_m) and math.isinf(base_range):
            self.active = np.asarray(alive, dtype=bool).copy()
        else:
            self.active = active_mask(pos, alive, cfg.radio_range_m, base_range, base)
        if self._needs_hops:
            self.hops = self._hop_counts(pos, base, base_range)
        return self.active

    def _hop_counts_terrain(self, pos: np.ndarray, base: np.ndarray) -> np.ndarray:
        """Hop counts over the links that clear the terrain (breadth-first from the base)."""
        assert self.ground is not None  # terrain radios only
        hops = np.zeros(len(pos), dtype=np.int64)
        idx = np.flatnonzero(self.active)
        if len(idx) == 0:
            return hops
        p = pos[idx]
        k = len(idx)
        pairs = self.ground.link_pairs(p)
        at_base = np.flatnonzero(self.ground.links_to_base(p, base))
        return self._bfs_hops(hops, idx, k, pairs, at_base)

    @staticmethod
    def _bfs_hops(
        hops: np.ndarray, idx: np.ndarray, k: int, pairs: np.ndarray, at_base: np.ndarray
    ) -> np.ndarray:
        rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.full(len(at_base), k), at_base])
        cols = np.concatenate([pairs[:, 1], pairs[:, 0], at_base, np.full(len(at_base), k)])
        graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(k + 1, k + 1)).tocsr()
        order, pred = breadth_first_order(graph, k, directed=True, return_predecessors=True)
        depth = np.zeros(k + 1, dtype=np.int64)
        for node in order[1:]:  # BFS order: the predecessor's depth is already known
            depth[node] = depth[pred[node]] + 1
        hops[idx] = depth[:k]
        return hops

    def _hop_counts(self, pos: np.ndarray, base: np.ndarray, base_range: float) -> np.ndarray:
        """Hop count of every active vehicle (0 for the others): compiled
        (:func:`vehicle_emu._kernels.hop_counts`) when available, else
        :meth:`_hop_counts_reference`."""
        if not _kernels.active() or math.isinf(self.config.radio_range_m):
            return self._hop_counts_reference(pos, base, base_range)
        r = self.config.radio_range_m
        return _kernels.hop_counts(pos, self.active, base, r, min(base_range, r))

    def _hop_counts_reference(
        self, pos: np.ndarray, base: np.ndarray, base_range: float
    ) -> np.ndarray:
        """The hop counts by scipy's breadth-first search over the neighbour pairs."""
        n = len(pos)
        hops = np.zeros(n, dtype=np.int64)
        idx = np.flatnonzero(self.active)
        if len(idx) == 0:
            return hops
        if math.isinf(self.config.radio_range_m):
            hops[idx] = 1
            return hops
        p = pos[idx]
        k = len(idx)
        pairs = neighbour_pairs(p, self.config.radio_range_m)
        at_base = np.flatnonzero(
            np.linalg.norm(p - base, axis=1) <= min(base_range, self.config.radio_range_m)
        )
        return self._bfs_hops(hops, idx, k, pairs, at_base)

    def transit_many(self, indices: list[int]) -> list[float | None]:
        """``[transit(i) for i in indices]``: the same fates, counters and random draws, in
        order; without hop counts (no latency, no loss) one array lookup for all."""
        if self._needs_hops:
            return [self.transit(i) for i in indices]
        if not indices:
            return []
        idx = np.asarray(indices, dtype=np.intp)
        active = self.active
        ok = np.zeros(len(idx), dtype=bool)
        inside = idx < len(active)
        ok[inside] = active[idx[inside]]
        self.n_dropped_inactive += len(idx) - int(np.count_nonzero(ok))
        return [0.0 if o else None for o in ok.tolist()]

    def transit(self, index: int) -> float | None:
        """Fate of one packet between vehicle ``index`` and the GCS (either direction).

        Returns the delay in seconds, or ``None`` if the packet does not get through.
        """
        if index >= len(self.active) or not self.active[index]:
            self.n_dropped_inactive += 1
            return None
        if not self._needs_hops:
            return 0.0
        h = int(self.hops[index])
        p = self.config.loss_per_hop
        if p > 0 and self.rng.random() >= (1.0 - p) ** h:
            self.n_dropped_loss += 1
            return None
        return h * self.config.latency_per_hop_s
