"""The compiled task-tree relaxation (planner._steiner_kernels) against the Python sweeps of
planner.steiner: the same nodes (bits), parents and fixed-point flag; CPython's math.hypot bit
for bit."""

import math

import numpy as np
import pytest

from planner import _kernels, _steiner_kernels, steiner

pytestmark = pytest.mark.skipif(
    not (_kernels.NUMBA and _steiner_kernels.APPLIES), reason="numba / CPython 3.11 only"
)


def test_py_hypot_is_cpython_hypot(rng):
    cases = [(0.0, 0.0), (-0.0, 3.0), (3.0, 4.0), (1e308, 1e308), (math.inf, math.nan)]
    cases += [(math.nan, 1.0), (1.0, 1e-170), (1e-200, 1.0), (-2.5, 0.0), (1e-300, 3e-301)]
    for a, b in cases:
        want, got = math.hypot(a, b), _steiner_kernels.py_hypot(a, b)
        assert want == got or (math.isnan(want) and math.isnan(got)), (a, b)
    n = 0
    for scale in (1e-300, 1e-150, 1e-5, 1.0, 1e3, 1e150, 1e300):
        x = rng.normal(0, 1, 40_000) * scale
        y = rng.normal(0, 1, 40_000) * scale * rng.choice([1, 1e-3, 1e-9, 1e-20], 40_000)
        x = np.where(rng.random(40_000) < 0.1, np.round(x, 1), x)
        for a, b in zip(x.tolist(), y.tolist()):
            assert math.hypot(a, b) == _steiner_kernels.py_hypot(a, b), (a, b)
            n += 1
    assert n == 280_000


def _same(a, b):
    return (
        b is not None
        and a[2] == b[2]
        and np.array_equal(a[1], b[1])
        and np.array_equal(a[0].view(np.int64), b[0].view(np.int64))
    )


@pytest.mark.parametrize("shortcuts", [True, False])
def test_compiled_relaxation_is_the_python_sweeps(rng, monkeypatch, shortcuts):
    monkeypatch.setattr(steiner, "RELAX_SHORTCUTS", shortcuts)
    spliced = fixed = 0
    for trial in range(120):
        m, w = int(rng.integers(1, 50)), rng.uniform(5, 500)
        tasks = rng.uniform(-w, w, (m, 2))
        if trial % 4 == 0:
            tasks = np.round(tasks, 0)
        if trial % 7 == 0 and m > 3:
            tasks[1] = tasks[0]
        nodes, parent = steiner._greedy_tree(np.zeros(2), tasks, float(rng.choice([0.0, 1.0])))
        moved = nodes.copy()
        moved[1 : 1 + m] += rng.normal(0, 0.05 * w, (m, 2))
        for sweeps in (0, 1, 3, 10):
            for nd in (nodes, moved):
                want = steiner._relax_steiner_python(nd, parent, m, sweeps)
                got = _steiner_kernels.relax_steiner(
                    nd, parent, m, sweeps, shortcuts, steiner._COINCIDE_RTOL, 100
                )
                assert _same(want, got), (trial, sweeps)
                spliced += len(want[0]) < len(nd)
                fixed += want[2]
    assert spliced > 0 and fixed > 0


def test_compiled_relaxation_of_high_degree_steiner_nodes(rng):
    """Steiner nodes with 4-7 neighbours (the geometric median), including coincident inputs."""
    medians = 0
    for trial in range(200):
        k = int(rng.integers(3, 7))  # tasks under one Steiner node
        tasks = rng.uniform(-50, 50, (k, 2))
        if trial % 3 == 0:
            tasks[1] = tasks[0]
        if trial % 5 == 0:
            tasks = np.round(tasks)
        nodes = np.vstack([[0.0, 0.0], tasks, tasks.mean(axis=0) + rng.normal(0, 5, 2)])
        parent = np.array([-1, *([k + 1] * k), 0], dtype=np.int64)
        want = steiner._relax_steiner_python(nodes, parent, k, 3)
        got = _steiner_kernels.relax_steiner(nodes, parent, k, 3, True, steiner._COINCIDE_RTOL, 100)
        assert _same(want, got), trial
        medians += len(want[0]) == len(nodes)
    assert medians > 0


def test_subnormal_distances_fall_back(rng):
    """A subnormal largest coordinate is not reproduced bit for bit: the kernel declines."""
    nodes = np.array([[0.0, 0.0], [1e-310, 0.0], [0.0, 2e-310], [3e-310, 3e-310], [1e-310, 1e-310]])
    parent = np.array([-1, 4, 4, 4, 0], dtype=np.int64)
    assert _steiner_kernels.relax_steiner(nodes, parent, 3, 3, True, 1e-12, 100) is None
    assert steiner._relax_steiner(nodes, parent, 3, 3)[1].shape  # the Python sweeps ran
