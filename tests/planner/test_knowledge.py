"""The asynchronous message layer: the vectorised hop against loops, and its semantics."""

import numpy as np

import pytest

from planner import _kernels, _message_kernels, knowledge
from planner.knowledge import (
    Knowledge,
    KnowledgeDense,
    MessageLayer,
    propagate_entries,
    propagate_stamps,
    propagate_stamps_dense,
    propagate_stamps_reference,
)


def test_propagation_matches_reference(rng):
    for _ in range(100):
        n = int(rng.integers(2, 30))
        stamp = rng.integers(-1, 20, (n, n + 1))
        pairs = rng.integers(0, n, (int(rng.integers(0, 80)), 2))
        pairs = pairs[pairs[:, 0] != pairs[:, 1]]
        assert (propagate_stamps(stamp, pairs) == propagate_stamps_reference(stamp, pairs)).all()
        # with an age limit, entries older than the limit are not forwarded
        t_sent, age_max = int(stamp.max()), int(rng.integers(0, 25))
        fresh = np.where(t_sent - stamp <= age_max, stamp, -1)
        expected = np.maximum(propagate_stamps_reference(fresh, pairs), stamp)
        assert (propagate_stamps(stamp, pairs, t_sent, age_max) == expected).all()


def test_level_by_level_fallback_for_very_old_ages(rng):
    """Ages beyond the float64 exponent encoding take the one-product-per-level path."""
    n = 40
    stamp = rng.integers(-1, 300, (n, n))
    pairs = rng.integers(0, n, (200, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    assert (
        propagate_stamps(stamp, pairs, 300, 299) == propagate_stamps_reference(stamp, pairs)
    ).all()


def _chain(n, spacing):
    return np.stack([np.arange(n) * spacing + 0.5, np.zeros(n)], axis=1)


def _hold(k, pos, alive, steps, *args, **kwargs):
    """``k.update`` at each step of ``steps`` with every drone fixed at ``pos`` (nothing is
    delivered at step 0); ``args``/``kwargs``: the update's range, cut-off and base arguments."""
    for t in steps:
        first = t == 0
        k.update(t, None if first else pos, None if first else alive, pos, alive, *args, **kwargs)


def test_reports_travel_one_hop_per_step_and_tree_floods_from_base():
    n = 5
    pos = _chain(n, 1.6)  # base at 0, drone 0 at 0.5 (only it reaches the base), links 1.6 <= r
    alive = np.ones(n, bool)
    k = Knowledge.empty(n, 20)
    prev = None
    for t in range(6):
        k.update(
            t,
            prev,
            alive if prev is not None else None,
            pos,
            alive,
            2.0,
            2.0,
            10,
            100.0,
            np.zeros(2),
        )
        prev = pos
        if t == 0:
            assert (k.stamp == np.where(np.eye(n, dtype=bool), 0, -1)).all()
        # drone 0 hears about drone j after j steps, stamped j steps ago
        for j in range(1, n):
            expected = t - j if t >= j else -1
            assert k.stamp[0, j] == expected
        # the tree computed at step s reaches drone i (i hops from the base link) at s + 1 + i
        for i in range(n):
            assert k.tree_stamp[i] == (t - 1 - i if t - 1 - i >= 0 else -1)


def test_age_and_distance_cutoffs_and_dead_drones():
    n = 3
    pos = _chain(n, 1.5)
    alive = np.ones(n, bool)
    k = Knowledge.empty(n, 30)
    _hold(k, pos, alive, range(4), 2.0, 2.0, age_max_steps=1, dist_max_m=100.0, base_m=np.zeros(2))
    # with an age limit of 1 step, drone 0 can know drone 1 (1 hop) but never drone 2 (2 hops)
    assert k.stamp[0, 1] == 2 and k.stamp[0, 2] == -1
    k2 = Knowledge.empty(n, 30)
    _hold(k2, pos, alive, range(4), 2.0, 2.0, 10, dist_max_m=2.0, base_m=np.zeros(2))
    assert k2.stamp[0, 1] >= 0 and k2.stamp[0, 2] == -1  # drone 2 is 3.0 away > 2.0
    dead = alive.copy()
    dead[1] = False
    k2.update(4, pos, alive, pos, dead, 2.0, 2.0, 10, 2.0, np.zeros(2))
    assert (k2.stamp[1] == -1).all() and k2.tree_stamp[1] == -1


def test_broadcast_after_move_shows_direct_neighbours_where_they_are_now():
    """Broadcasting after the move: a j-hop report is j - 1 steps old, still one hop per step."""
    n = 5
    pos = _chain(n, 1.6)
    alive = np.ones(n, bool)
    k = Knowledge.empty(n, 20)
    prev = None
    for t in range(6):
        k.update(
            t,
            prev,
            alive if prev is not None else None,
            pos,
            alive,
            2.0,
            2.0,
            10,
            100.0,
            np.zeros(2),
            after_move=True,
        )
        prev = pos
        if t == 0:  # nothing has been broadcast before the first step
            assert (k.stamp == np.where(np.eye(n, dtype=bool), 0, -1)).all()
            continue
        for j in range(1, n):
            expected = t - j + 1 if t >= j else -1
            assert k.stamp[0, j] == expected
        for i in range(n):
            assert k.tree_stamp[i] == (t - 1 - i if t - 1 - i >= 0 else -1)


def test_after_move_links_use_the_positions_at_the_current_step():
    """A drone that moved into range during the last step is heard now; one lost is not."""
    pos0 = np.array([[0.5, 0.0], [5.0, 0.0], [2.0, 0.0]])
    pos1 = np.array([[0.5, 0.0], [2.3, 0.0], [2.0, 0.0]])
    alive0 = np.ones(3, bool)
    alive1 = np.array([True, True, False])  # drone 2 lost during step 0
    k = Knowledge.empty(3, 5)
    k.update(0, None, None, pos0, alive0, 2.0, 2.0, 10, 100.0, np.zeros(2), after_move=True)
    k.update(1, pos0, alive0, pos1, alive1, 2.0, 2.0, 10, 100.0, np.zeros(2), after_move=True)
    assert k.stamp[0, 1] == 1  # 1.8 apart at step 1: heard, where it is now
    assert k.stamp[0, 2] == -1  # it was 1.5 away at step 0, but the lost send nothing
    before = Knowledge.empty(3, 5)
    before.update(0, None, None, pos0, alive0, 2.0, 2.0, 10, 100.0, np.zeros(2))
    before.update(1, pos0, alive0, pos1, alive1, 2.0, 2.0, 10, 100.0, np.zeros(2))
    assert before.stamp[0, 1] == -1 and before.stamp[0, 2] == 0  # links at step 0: the opposite


def test_forget_unheard_drops_lost_neighbours_at_once():
    n = 3
    pos = _chain(n, 1.5)
    alive = np.ones(n, bool)
    kept, dropped = Knowledge.empty(n, 10), Knowledge.empty(n, 10)
    prev = None
    for t in range(4):
        a = alive.copy()
        if t >= 3:
            a[1] = False
        for k, forget in ((kept, False), (dropped, True)):
            k.update(
                t,
                prev,
                alive if prev is not None else None,
                pos,
                a,
                2.0,
                2.0,
                10,
                100.0,
                np.zeros(2),
                after_move=True,
                forget_unheard=forget,
            )
        prev = pos
    # drone 1 (1.5 from drone 0, within r = 2) was lost during step 2: heard last at step 2
    assert kept.stamp[0, 1] == 2
    assert dropped.stamp[0, 1] == -1
    # drone 2 is 3.0 from drone 0: out of radio range, so its relayed report is kept either way
    assert kept.stamp[0, 2] == 1 and dropped.stamp[0, 2] == 1  # relayed by 1 at step 2


# bit sets (as shipped), or the exponent encoding with a dense / mixed / sparse x sparse product
KERNELS = [(16, 0.25), (0, 0.0), (0, 0.25), (0, 2.0)]


@pytest.mark.parametrize("bit_levels,sparse_below", KERNELS)
def test_entry_propagation_gives_the_dense_tables(rng, monkeypatch, bit_levels, sparse_below):
    """The entry-list hop against the previous dense kernel: identical integer tables."""
    monkeypatch.setattr(knowledge, "_BITSET_MAX_LEVELS", bit_levels)
    monkeypatch.setattr(knowledge, "_SPARSE_ENTRY_FRACTION", sparse_below)
    for _ in range(200):
        n, k = int(rng.integers(1, 40)), int(rng.integers(1, 50))
        stamp = rng.integers(-1, 20, (n, k))
        stamp[rng.random((n, k)) < rng.random()] = -1  # from nearly full to nearly empty
        pairs = rng.integers(0, n, (int(rng.integers(0, 120)), 2))
        pairs = pairs[pairs[:, 0] != pairs[:, 1]]  # repeated links included
        assert (propagate_stamps(stamp, pairs) == propagate_stamps_dense(stamp, pairs)).all()
        t_sent, age_max = int(stamp.max()), int(rng.integers(0, 25))
        assert (
            propagate_stamps(stamp, pairs, t_sent, age_max)
            == propagate_stamps_dense(stamp, pairs, t_sent, age_max)
        ).all()
        # the entry kernel itself: forwarded entries only, row-major, one per (row, col)
        r, c = np.nonzero(stamp >= 0)
        nr, nc, ns = propagate_entries(r, c, stamp[r, c], n, k, pairs, t_sent, age_max)
        key = nr * k + nc
        assert (np.diff(key) > 0).all()
        fresh = np.where(stamp >= max(t_sent - age_max, 0), stamp, -1)
        table = np.full((n, k), -1)
        table[nr, nc] = ns
        expected = propagate_stamps_reference(fresh, pairs) if len(pairs) else fresh
        assert (table == expected).all()


def test_entry_propagation_sorting_fallback_for_very_old_ages(rng):
    n, k = 30, 45
    stamp = rng.integers(-1, 400, (n, k))
    pairs = rng.integers(0, n, (150, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    r, c = np.nonzero(stamp >= 0)
    nr, nc, ns = propagate_entries(r, c, stamp[r, c], n, k, pairs, 400, 399)
    table = np.full((n, k), -1)
    table[nr, nc] = ns
    assert (np.diff(nr * k + nc) > 0).all()
    assert (table == propagate_stamps_reference(stamp, pairs)).all()


@pytest.mark.parametrize("after_move", [False, True])
@pytest.mark.parametrize("forget_unheard", [False, True])
@pytest.mark.parametrize("bit_levels,sparse_below", KERNELS)
def test_entry_knowledge_gives_the_dense_tables(
    rng, monkeypatch, after_move, forget_unheard, bit_levels, sparse_below
):
    """Whole episodes (moving swarm, losses, both broadcast timings, all cut-offs): the entry-list
    Knowledge and the previous dense one hold identical stamps, tree stamps and views."""
    monkeypatch.setattr(knowledge, "_BITSET_MAX_LEVELS", bit_levels)
    monkeypatch.setattr(knowledge, "_SPARSE_ENTRY_FRACTION", sparse_below)
    for _ in range(6):
        n, n_steps = int(rng.integers(2, 90)), 30
        age_max, dist_max = int(rng.integers(0, 6)), float(rng.uniform(1.0, 8.0))
        new, old = Knowledge.empty(n, n_steps), KnowledgeDense.empty(n, n_steps)
        pos = rng.uniform(-6, 6, (n, 2))
        alive = np.ones(n, bool)
        prev = (None, None)
        for t in range(n_steps):
            pos_t = pos + rng.normal(0, 0.4, pos.shape)
            alive_t = alive & (rng.random(n) > 0.04)
            for k in (new, old):
                k.update(
                    t,
                    prev[0],
                    prev[1],
                    pos_t,
                    alive_t,
                    2.0,
                    2.5,
                    age_max,
                    dist_max,
                    np.zeros(2),
                    after_move=after_move,
                    forget_unheard=forget_unheard,
                )
            assert np.array_equal(new.stamp, old.stamp)
            assert np.array_equal(new.tree_stamp, old.tree_stamp)
            assert np.array_equal(new.rows, old.rows) and np.array_equal(new.cols, old.cols)
            assert np.array_equal(new.entry_rows, old.entry_rows)
            assert np.array_equal(new.entry_cols, old.entry_cols)
            assert np.array_equal(new.entry_believed_m, old.entry_believed_m)
            assert np.array_equal(new.known_view, old.known_view)
            # the entry list is the table
            r, c = np.nonzero(new.stamp >= 0)
            assert np.array_equal(new.held_rows, r) and np.array_equal(new.held_cols, c)
            assert np.array_equal(new.held_stamps, new.stamp[r, c])
            prev, pos, alive = (pos_t, alive_t), pos_t, alive_t


def test_message_layer_same_with_a_drone_coming_back(rng):
    """A drone absent from one tick and back at the next (live use) gets its own entry again."""
    n = 12
    layer = MessageLayer(n, 10, 2.0, 2.0, 3, 6.0, 15, after_move=True, forget_unheard=True)
    ref = KnowledgeDense.empty(n, 11)
    pos = rng.uniform(-2, 2, (n, 2))
    prev = (None, None)
    for t in range(8):
        alive = np.ones(n, bool)
        if t in (3, 4):
            alive[5] = False
        layer.step(t, pos, alive, np.zeros(2), t)
        ref.update(
            t,
            prev[0],
            prev[1],
            pos,
            alive,
            2.0,
            2.0,
            3,
            6.0,
            np.zeros(2),
            after_move=True,
            forget_unheard=True,
        )
        assert np.array_equal(layer.knowledge.stamp, ref.stamp)
        prev = (pos, alive)


@pytest.mark.parametrize("after_move", [False, True])
@pytest.mark.parametrize("forget_unheard", [False, True])
@pytest.mark.parametrize("max_per_bit", [1e-9, 2.0, 1e9])
def test_fused_update_is_the_unfused_one(rng, monkeypatch, after_move, forget_unheard, max_per_bit):
    """The compiled update (own entries, hop, cut-offs and view in one pass,
    :func:`planner._message_kernels.knowledge_step`) against the unfused path it replaces, with the
    cost model forced to the bit sets (1e9), to the per-entry maximum (1e-9) or left as shipped:
    identical arrays (values and dtypes), swarms large and small, losses, a drone coming back."""
    monkeypatch.setattr(knowledge, "_MAX_PER_BIT_WORD", max_per_bit)
    fused_step = _message_kernels.knowledge_step
    calls = {"fused": 0}

    def counted(*args: object) -> object:
        out = fused_step(*args)  # type: ignore[arg-type]
        calls["fused"] += out[0] is not None
        return out

    def unfused(*args: object) -> object:
        return None, args[-1]

    for trial in range(8):
        n, n_steps = int(rng.integers(2, 150)), 25
        age_max, dist_max = int(rng.integers(0, 6)), float(rng.uniform(1.0, 8.0))
        fused, ref = Knowledge.empty(n, n_steps), Knowledge.empty(n, n_steps)
        pos = rng.uniform(-6, 6, (n, 2)) * rng.uniform(0.2, 2.0)
        alive = np.ones(n, bool)
        prev = (None, None)
        for t in range(n_steps):
            pos_t = pos + rng.normal(0, 0.4, pos.shape)
            alive_t = alive & (rng.random(n) > 0.04)
            if t == 12:
                alive_t[0] = True  # back after a loss (live use)
            for kn, step in ((fused, counted), (ref, unfused)):
                monkeypatch.setattr(_message_kernels, "knowledge_step", step)
                kn.update(
                    t,
                    prev[0],
                    prev[1],
                    pos_t,
                    alive_t,
                    2.0,
                    2.5,
                    age_max,
                    dist_max,
                    np.zeros(2),
                    after_move=after_move,
                    forget_unheard=forget_unheard,
                )
            for name in (
                "held_rows",
                "held_cols",
                "held_stamps",
                "tree_stamp",
                "rows",
                "cols",
                "entry_rows",
                "entry_cols",
                "entry_believed_m",
            ):
                a, b = getattr(fused, name), getattr(ref, name)
                assert a.dtype == b.dtype and np.array_equal(a, b), (trial, t, name)
            # each view entry's stamp (from the fused pass, or built on request and kept until the
            # next update: asked every tick, so a stamp kept past an update would show here) is
            # the stamp table's
            table = np.asarray(ref.stamp)
            want = table[ref.rows[ref.entry_rows], ref.cols[ref.entry_cols]]
            for kn in (fused, ref):
                got = kn.view_entry_stamps()
                assert got.dtype == np.int64 and np.array_equal(got, want), (trial, t)
            prev, pos, alive = (pos_t, alive_t), pos_t, alive_t
    assert calls["fused"] > 0 or not _kernels.NUMBA


def test_fused_update_declines_what_it_cannot_read():
    """Entries not row-major, a column out of range, a stamp past the sending step, a step past the
    history: no result (the caller runs the unfused path)."""
    n = 4
    hist = np.zeros((6, n, 2))
    alive = np.ones(n, bool)
    pairs = np.array([[0, 1], [1, 2]])

    def step(r, c, s, t_step=3, t_sent=3):  # type: ignore[no-untyped-def]
        return _message_kernels.knowledge_step(
            np.array(r),
            np.array(c),
            np.array(s),
            alive,
            False,
            True,
            np.arange(n),
            pairs,
            t_sent,
            3,
            2.0,
            t_step,
            hist,
            np.zeros((n, 2)),
            5.0,
            1.0,
            False,
            _message_kernels.knowledge_scratch(),
        )[0]

    if not _kernels.NUMBA:
        return
    assert step([0, 1, 2], [1, 2, 3], [2, 2, 3]) is not None
    assert step([1, 0], [0, 1], [2, 2]) is None  # rows not ascending
    assert step([0, 0], [2, 1], [2, 2]) is None  # columns not ascending in a row
    assert step([0, 0], [1, 1], [2, 2]) is None  # a repeated entry
    assert step([0], [n], [2]) is None  # column out of range
    assert step([n], [0], [2]) is None  # row out of range
    assert step([0], [1], [3], t_sent=2) is None  # stamp past the sending step
    assert step([0], [1], [2], t_step=6) is None  # past the history


def test_tree_stamp_flood_compiled_is_the_numpy_one(rng, monkeypatch):
    """_flood_tree_stamp compiled (planner._message_kernels.flood_tree_stamp) against its NumPy
    lines: random stamps, links (repeated and empty), drones on the base-reach circle and past it;
    an index out of range is declined with nothing written."""
    from planner.knowledge import _flood_tree_stamp

    if not _kernels.NUMBA:
        pytest.skip("needs Numba")
    for trial in range(30):
        n_all = int(rng.integers(1, 60))
        idx = np.sort(rng.choice(n_all, int(rng.integers(0, n_all + 1)), replace=False))
        pos = rng.uniform(-4, 4, (len(idx), 2))
        base = rng.uniform(-1, 1, 2)
        reach = float(rng.uniform(0.5, 3.0))
        if len(pos):
            pos[0] = base + [reach, 0.0]  # on the circle: |d| <= reach by the same sqrt
        n_pairs = int(rng.integers(0, 3 * len(idx) + 1)) if len(idx) > 1 else 0
        pairs = rng.integers(0, max(len(idx), 1), (n_pairs, 2))
        stamps = rng.integers(-1, 20, n_all).astype(np.int64)
        fast, slow = stamps.copy(), stamps.copy()
        _flood_tree_stamp(fast, idx, pairs, pos, base, reach, 21)
        with monkeypatch.context() as mp:
            mp.setattr(_message_kernels, "flood_tree_stamp", lambda *a: False)
            _flood_tree_stamp(slow, idx, pairs, pos, base, reach, 21)
        assert np.array_equal(fast, slow), trial
    kept = stamps.copy()
    bad = np.array([[0, len(idx) + 5]])
    assert not _message_kernels.flood_tree_stamp(kept, idx, bad, pos, base, reach, 21)
    assert np.array_equal(kept, stamps)
