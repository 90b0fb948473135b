"""The compiled greedy task tree (planner._greedy_kernels) against the NumPy build of
planner.steiner (``_greedy_tree_python``): the same nodes (bits) and parents; its element
formulas against NumPy's complex ``abs`` and products, libm's ``hypot`` against NumPy's scalar
``abs``; its probe and its declines."""

import ctypes
import ctypes.util

import numpy as np
import pytest

from planner import _greedy_kernels, _kernels, _steiner_kernels, steiner

pytestmark = pytest.mark.skipif(
    not (_kernels.NUMBA and _steiner_kernels.APPLIES), reason="numba / CPython 3.11 only"
)

REF = steiner._GREEDY_REFERENCE


def _bits(a):
    return np.ascontiguousarray(a).view(np.int64)


def _same_tree(want, got):
    return (
        got is not None
        and want[0].shape == got[0].shape
        and np.array_equal(_bits(want[0]), _bits(got[0]))
        and np.array_equal(want[1], got[1])
    )


def _complex(rng, shape, signed_zeros=True):
    """Values over many scales, with exact zeros, -0.0, equal parts and subnormal parts."""
    n = int(np.prod(shape))
    scale = 10.0 ** rng.uniform(-5, 6, (n, 2))
    xy = rng.normal(0, 1, (n, 2)) * scale
    kind = rng.random((n, 2))
    xy[kind < 0.05] = 0.0
    if signed_zeros:
        xy[(kind >= 0.05) & (kind < 0.1)] = -0.0
    xy[(kind >= 0.1) & (kind < 0.12)] = 3e-310
    same = rng.random(n) < 0.05
    xy[same, 1] = xy[same, 0]
    out = np.empty(n, dtype=np.complex128)
    out.real, out.imag = xy[:, 0], xy[:, 1]
    return out.reshape(shape)


def _emulated_product(a, b):
    """The kernel's complex product of two broadcast arrays, element by element."""
    a, b = np.broadcast_arrays(np.asarray(a, np.complex128), np.asarray(b, np.complex128))
    return _greedy_kernels.cmul_array(a.ravel(), b.ravel()).reshape(a.shape)


def test_kernel_runs_on_this_machine(rng):
    """The probe passes here, so the tests below compare the kernel, not the fallback."""
    assert _greedy_kernels.matches_numpy(REF)
    tasks = rng.uniform(-50, 50, (30, 2))
    assert _greedy_kernels.greedy_tree(np.zeros(2), tasks, 1.0, REF) is not None


@pytest.mark.parametrize("n", [*range(1, 18), 31, 64, 1000, 20_000])
def test_cabs_is_numpy_abs(rng, n):
    z = _complex(rng, (n,))
    assert np.array_equal(_bits(np.abs(z)), _bits(_greedy_kernels.cabs_array(z)))


@pytest.mark.parametrize("n", [*range(1, 18), 31, 64, 1000, 20_000])
def test_cmul_is_numpy_multiply(rng, n):
    a, b = _complex(rng, (n,)), _complex(rng, (n,))
    f = rng.normal(0, 1, n) * 10.0 ** rng.uniform(-5, 6, n)
    f[rng.random(n) < 0.1] = 0.0
    f[rng.random(n) < 0.1] = -0.0
    for want, (x, y) in (
        (a * b, (a, b)),
        (a.conjugate() * b, (a.conjugate(), b)),
        (a * f, (a, f)),  # the float is cast to complex (imaginary +0.0)
        (f * a, (f, a)),
    ):
        assert np.array_equal(
            _bits(want.view(np.float64)), _bits(_emulated_product(x, y).view(np.float64))
        )


@pytest.mark.parametrize("f", [1, 2, 3, 7, 16, 17, 50, 150])
@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_cmul_is_numpy_multiply_under_broadcasting(rng, f, n):
    """The products of ``_fermat_complex(u, w, y)`` inside the build, u, w (n,) and y an (F, 1)
    view: (n,) or (F, n) complex times an (F, n) float (cast to complex), and (F, n) conjugate times
    (F, n). (A complex (n,) times a complex (F, 1) with a one-element result would take NumPy's
    scalar loop, unfused: the build has no such product.)"""
    for _ in range(20 if f * n <= 3 else 2):
        u, w = _complex(rng, (n,)), _complex(rng, (n,))
        y = _complex(rng, (f + 3,))[:f, None]
        g = np.abs(_complex(rng, (f, n)))
        ab, ac, bc = (w - u) * g, (y - u) * g, (y - w) * g
        for x, z in (
            (w - u, g),
            (y - u, g),
            (y - w, g),
            (ab.conjugate(), ac),
            (ab.conjugate(), bc),
            (ac.conjugate(), bc),
            (g, ab),
            (g, ac + ab),
        ):
            want = x * z
            got = _emulated_product(x, z)
            assert np.array_equal(_bits(want.view(np.float64)), _bits(got.view(np.float64)))


def test_hypot_is_libm_and_numpy_scalar_abs(rng):
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    libm.hypot.restype = ctypes.c_double
    libm.hypot.argtypes = [ctypes.c_double, ctypes.c_double]
    z = _complex(rng, (30_000,))
    x, y = z.real.copy(), z.imag.copy()
    got = _greedy_kernels.hypot_array(x, y)
    want_libm = np.array([libm.hypot(a, b) for a, b in zip(x.tolist(), y.tolist())])
    want_numpy = np.array([abs(v) for v in z[:5000]])  # numpy.complex128 scalars
    assert np.array_equal(_bits(got), _bits(want_libm))
    assert np.array_equal(_bits(got[:5000]), _bits(want_numpy))


@pytest.mark.parametrize("cb", [0.0, 1.0, 0.37])
def test_split_and_direct_costs_are_numpy(rng, cb):
    checked = 0
    for trial in range(60):
        f, n = int(rng.integers(1, 200)), int(rng.integers(1, 4))
        pos = rng.uniform(-50, 50, (6, 2))
        if trial % 3 == 0:
            pos = np.round(pos / 20)
        pos_z = pos[:, 0] + 1j * pos[:, 1]
        tasks = rng.uniform(-50, 50, (f + 2, 2))
        if trial % 2 == 0:
            tasks = np.round(tasks / 20)
        tasks[:3] = pos[:3]
        row_z = tasks[:, 0] + 1j * tasks[:, 1]
        top, bottom = rng.integers(0, 6, n), rng.integers(0, 6, n)
        n_below = rng.integers(0, 30, n).astype(float)
        y = row_z[:f, None]
        want = steiner._split_costs(pos_z[top], pos_z[bottom], y, n_below, cb)
        got = _greedy_kernels.split_costs(pos_z[top], pos_z[bottom], y, n_below, cb)
        assert np.array_equal(_bits(want[0]), _bits(got[0])), trial
        assert np.array_equal(_bits(want[1]), _bits(got[1])), trial
        want_d = steiner._direct_costs(y, pos_z[top], cb)
        assert np.array_equal(_bits(want_d), _bits(_greedy_kernels.direct_costs(y, pos_z[top], cb)))
        checked += np.isinf(want[0]).sum() > 0
    assert checked > 0  # some splits at u or w (inf) were compared


def _task_sets(rng):
    """(base, tasks, cb): random fields in metres (half-width 2-50 km) and in paper units
    (+-5, +-50), and degenerate ones."""
    sets = []
    for trial in range(320):
        m = int(rng.integers(1, 151)) if trial % 4 else int(rng.integers(1, 12))
        half = float(rng.choice([5.0, 50.0, 2_000.0, 10_000.0, 50_000.0]))
        tasks = rng.uniform(-half, half, (m, 2))
        base = np.zeros(2) if trial % 3 else rng.uniform(-half / 5, half / 5, 2)
        cb = float(rng.choice([0.0, 1.0, 1.0, 0.5, 3.0, rng.uniform(0, 4)]))
        sets.append((base, tasks, cb))
    for cb in (0.0, 1.0, 0.25, 2.0):
        for m in (1, 2, 3, 5, 12, 40):
            base = np.array([0.5, -0.5])
            ones = np.ones((m, 2))
            line = np.stack([np.arange(1, m + 1), np.zeros(m)], axis=1) * 3.0
            diag = np.stack([np.arange(m), np.arange(m)], axis=1) - m / 2
            g = int(np.ceil(np.sqrt(m)))
            grid = np.stack(np.meshgrid(np.arange(g), np.arange(g)), axis=-1).reshape(-1, 2)[:m]
            mixed = rng.uniform(-5, 5, (m, 2))
            mixed[::2] = mixed[0]  # coincident
            mixed[1::3] = base  # on the base
            for tasks in (ones, base + 0 * ones, line, diag, grid - 1.5, 5.0 * grid, mixed):
                sets.append((base, np.array(tasks, dtype=float), cb))
            sets.append((np.zeros(2), -0.0 * ones, cb))  # signed zeros
    return sets


def test_kernel_is_the_numpy_build(rng):
    steiner_nodes = task_parents = 0
    for i, (base, tasks, cb) in enumerate(_task_sets(rng)):
        want = steiner._greedy_tree_python(base, tasks, cb)
        got = _greedy_kernels.greedy_tree(base, tasks, cb, REF)
        assert _same_tree(want, got), (i, len(tasks), cb)
        m = len(tasks)
        steiner_nodes += len(want[0]) > m + 1
        task_parents += np.any((want[1] >= 1) & (want[1] <= m))
    assert steiner_nodes > 100 and task_parents > 100


def test_kernel_is_the_all_numpy_build(rng, monkeypatch):
    """Against the reference with NumPy's argmin too (``_kernels.ENABLED`` off there)."""
    for trial in range(40):
        m = int(rng.integers(1, 80))
        tasks = rng.uniform(-20, 20, (m, 2))
        if trial % 2:
            tasks = np.round(tasks / 4)
        cb = float(rng.choice([0.0, 1.0]))
        got = _greedy_kernels.greedy_tree(np.zeros(2), tasks, cb, REF)
        monkeypatch.setattr(_kernels, "ENABLED", False)
        want = steiner._greedy_tree(np.zeros(2), tasks, cb)
        monkeypatch.setattr(_kernels, "ENABLED", True)
        assert _same_tree(want, got), trial


def test_build_task_tree_is_unchanged(rng, monkeypatch):
    for m, cb in ((1, 1.0), (7, 0.0), (60, 1.0), (150, 0.5)):
        tasks = rng.uniform(-5, 5, (m, 2))
        fast = steiner.build_task_tree(np.zeros(2), tasks, cb)
        monkeypatch.setattr(_kernels, "ENABLED", False)
        slow = steiner.build_task_tree(np.zeros(2), tasks, cb)
        monkeypatch.setattr(_kernels, "ENABLED", True)
        assert np.array_equal(_bits(fast.nodes_m), _bits(slow.nodes_m))
        assert np.array_equal(fast.parent, slow.parent)


def test_declines(rng, monkeypatch):
    tasks = rng.uniform(-5, 5, (20, 2))
    base = np.zeros(2)
    assert _greedy_kernels.greedy_tree(base, tasks, 1.0, REF) is not None
    nan = tasks.copy()
    nan[3, 1] = np.nan
    assert _greedy_kernels.greedy_tree(base, nan, 1.0, REF) is None
    assert _greedy_kernels.greedy_tree(base, tasks * 1e120, 1.0, REF) is None
    assert _greedy_kernels.greedy_tree(base, tasks, 1e120, REF) is None
    assert _greedy_kernels.greedy_tree(base, tasks, np.inf, REF) is None
    # a subnormal side in a scalar Fermat point: declined there, the NumPy build runs
    tiny = tasks * 1e-309
    assert _greedy_kernels.greedy_tree(base, tiny, 1.0, REF) is None
    want = steiner._greedy_tree_python(base, tiny, 1.0)
    assert _same_tree(want, steiner._greedy_tree(base, tiny, 1.0))
    monkeypatch.setattr(_kernels, "ENABLED", False)
    assert _greedy_kernels.greedy_tree(base, tasks, 1.0, REF) is None
    monkeypatch.setattr(_kernels, "ENABLED", True)
    monkeypatch.setattr(_greedy_kernels, "_MATCHES", False)  # NumPy not as emulated
    assert _greedy_kernels.greedy_tree(base, tasks, 1.0, REF) is None
    assert _same_tree(
        steiner._greedy_tree_python(base, tasks, 1.0), steiner._greedy_tree(base, tasks, 1.0)
    )


def test_probe_catches_a_different_numpy():
    """A NumPy whose complex abs is the plain formula, or any result off by one ulp, fails."""

    def plain_abs(y, p, cb):
        d = y - p
        return (1.0 + cb) * np.sqrt(d.real * d.real + d.imag * d.imag)

    assert _greedy_kernels._probe(REF)
    assert not _greedy_kernels._probe(REF._replace(direct_costs=plain_abs))
    off_by_one_ulp = REF._replace(
        split_costs=lambda *a: tuple(np.nextafter(c, np.inf) for c in steiner._split_costs(*a))
    )
    assert not _greedy_kernels._probe(off_by_one_ulp)
    assert not _greedy_kernels._probe(REF._replace(fermat_scalar=lambda *a: (0.0, 0.0, -1)))


def _unfused(a, b):
    """a * b by the textbook formula (NumPy's scalar loop), no fused multiply-add."""
    a, b = np.broadcast_arrays(np.asarray(a, np.complex128), np.asarray(b, np.complex128))
    out = np.empty(a.shape, dtype=np.complex128)
    out.real = a.real * b.real - a.imag * b.imag
    out.imag = a.real * b.imag + a.imag * b.real
    return out


def _split_costs_unfused_when_tiny(u, w, y, n_below, cb):
    """``steiner._split_costs`` as a NumPy would compute it whose complex products of one-element
    triangles took the unfused scalar loop (a copy of ``_fermat_complex`` with ``_unfused``)."""
    if u.size * y.size != 1:
        return steiner._split_costs(u, w, y, n_below, cb)
    a, b, c = u, w, y
    ab, ac = b - a, c - a
    scale = np.maximum(np.maximum(np.abs(ab), np.abs(ac)), steiner._TINY)
    inv_scale = 1.0 / scale
    ab, ac, bc = _unfused(ab, inv_scale), _unfused(ac, inv_scale), _unfused(c - b, inv_scale)
    cross = np.abs(ab.real * ac.imag - ab.imag * ac.real)
    den_a = cross + steiner._SQRT3 * _unfused(ab.conjugate(), ac).real
    den_b = cross - steiner._SQRT3 * _unfused(ab.conjugate(), bc).real
    den_c = cross + steiner._SQRT3 * _unfused(ac.conjugate(), bc).real
    at_a, at_b, at_c = den_a <= 0.0, den_b <= 0.0, den_c <= 0.0
    den_a = np.where(at_a, 1.0, den_a)
    den_b = np.where(at_b, 1.0, den_b)
    den_c = np.where(at_c, 1.0, den_c)
    wa, wb, wc = den_b * den_c, den_a * den_c, den_a * den_b
    total = wa + wb + wc
    z = a + _unfused(scale, _unfused(wb / total, ab) + _unfused(wc / total, ac))
    s = np.where(at_c, c, z)
    us, sy = np.abs(s - u), np.abs(y - s)
    detour = us + np.abs(w - s) - np.abs(w - u)
    cost = (detour + sy) + cb * ((us + sy) + n_below * detour)
    return np.where(at_a | at_b, np.inf, cost), cb * detour


def test_probe_catches_unfused_products_of_one_element_triangles(rng):
    """The probe's draws of the smallest shapes are enough to see the formula, not just the shape:
    the unfused copy agrees with NumPy elsewhere, and with the kernel only by chance there."""
    u, w = _complex(rng, (3,)), _complex(rng, (3,))
    y = _complex(rng, (5,))[:4, None]
    want = steiner._split_costs(u, w, y, np.ones(3), 1.0)
    same = _split_costs_unfused_when_tiny(u, w, y, np.ones(3), 1.0)
    assert np.array_equal(_bits(want[0]), _bits(same[0]))
    assert not _greedy_kernels._probe(REF._replace(split_costs=_split_costs_unfused_when_tiny))


@pytest.mark.parametrize("f", [1, 2, 3, 4])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_split_costs_of_few_triangles_are_numpy(rng, f, n):
    """The build's smallest shapes, where NumPy's loops take their tails (many draws)."""
    for _ in range(150):
        pos = _complex(rng, (5,), signed_zeros=False) * 1e-3
        u, w = pos[rng.integers(0, 5, n)], pos[rng.integers(0, 5, n)]
        y = _complex(rng, (f + 1,))[:f, None] * 1e-3
        n_below = rng.integers(0, 9, n).astype(float)
        cb = float(rng.choice([0.0, 1.0]))
        want = steiner._split_costs(u, w, y, n_below, cb)
        got = _greedy_kernels.split_costs(u, w, y, n_below, cb)
        assert np.array_equal(_bits(want[0]), _bits(got[0]))
        assert np.array_equal(_bits(want[1]), _bits(got[1]))
