"""DE/rand/1/bin and binary harmony search operators, checked by hand on tiny populations."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine.search import de, harmony


def test_mutation_by_hand() -> None:
    x = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0], [6.0, 8.0]])
    idx = np.array([[1, 2, 3], [0, 2, 3], [3, 0, 1], [2, 1, 0]])
    v = de.mutate(x, idx, 0.5)
    # v_i = x_r1 + F (x_r2 - x_r3)
    expected = np.array(
        [
            [2 + 0.5 * (4 - 6), 3 + 0.5 * (5 - 8)],
            [0 + 0.5 * (4 - 6), 1 + 0.5 * (5 - 8)],
            [6 + 0.5 * (0 - 2), 8 + 0.5 * (1 - 3)],
            [4 + 0.5 * (2 - 0), 5 + 0.5 * (3 - 1)],
        ]
    )
    np.testing.assert_allclose(v, expected)


def test_crossover_mask_by_hand() -> None:
    cross = np.array([[0.1, 0.9, 0.5], [0.95, 0.99, 0.97]])
    jrand = np.array([0.9, 0.4])  # -> j_rand = floor(0.9*3) = 2, floor(0.4*3) = 1
    take = de.crossover_mask(cross, jrand, 0.8)
    assert take.tolist() == [[True, False, True], [False, True, False]]


def test_binomial_crossover_takes_mutant_where_mask() -> None:
    rng = np.random.default_rng(3)
    x = np.zeros((5, 7))
    v = np.ones((5, 7))
    u = de.crossover(x, v, 0.0, rng)
    # CR = 0: only the forced coordinate comes from the mutant
    assert (u.sum(axis=1) == 1).all()
    u = de.crossover(x, v, 1.0, np.random.default_rng(3))
    assert (u == 1).all()


def test_reflection_by_hand() -> None:
    lo = np.array([-4.0, 0.01])
    hi = np.array([4.0, 20.0])
    t = np.array([[-5.0, 25.0], [4.5, -1.0], [0.0, 10.0], [-30.0, 100.0]])
    out = de.reflect(t.copy(), lo, hi)
    # -5 -> -3 (2*-4 - -5); 25 -> 15; 4.5 -> 3.5; -1 -> 1.02; inside unchanged;
    # far outside: reflected then clipped to the bound
    np.testing.assert_allclose(out, [[-3.0, 15.0], [3.5, 1.02], [0.0, 10.0], [-4.0, 0.01]])
    assert (out >= lo).all() and (out <= hi).all()


def test_donors_distinct_and_not_target() -> None:
    rng = np.random.default_rng(0)
    for size in (4, 5, 20):
        for _ in range(50):
            idx = de.donors(rng, size)
            assert idx.shape == (size, 3)
            for i, row in enumerate(idx):
                assert len(set(row.tolist())) == 3
                assert i not in row
    with pytest.raises(ValueError):
        de.donors(rng, 3)


def test_donors_uniform_over_others() -> None:
    rng = np.random.default_rng(1)
    counts = np.zeros(6)
    for _ in range(3000):
        counts += np.bincount(de.donors(rng, 6)[0], minlength=6)
    assert counts[0] == 0
    share = counts[1:] / counts[1:].sum()
    np.testing.assert_allclose(share, 0.2, atol=0.02)


def test_trial_maker_equals_reference_and_stays_in_box() -> None:
    rng = np.random.default_rng(5)
    x = rng.uniform(-4, 4, (8, 12))
    lo = np.full(12, -4.0)
    hi = np.full(12, 4.0)
    uni = np.random.default_rng(9).random(de.TrialMaker.n_uniforms(8, 12))
    maker = de.TrialMaker(8, 12, lo, hi, 0.6, 0.8)
    got = maker(x, uni).copy()
    # reference, from the same uniforms, with the pure functions
    keys = uni[:64].reshape(8, 8).copy()
    idx = de.donors_from_keys(keys)
    v = de.mutate(x, idx, 0.6)
    take = de.crossover_mask(uni[64 : 64 + 96].reshape(8, 12), uni[160:168], 0.8)
    ref = de.reflect(np.where(take, v, x), lo, hi)
    np.testing.assert_array_equal(got, ref)
    assert (got >= lo).all() and (got <= hi).all()
    np.testing.assert_array_equal(de.trials(x, 0.6, 0.8, lo, hi, np.random.default_rng(9)), got)


def test_greedy_selection_strict() -> None:
    x = np.array([[0.0], [1.0], [2.0]])
    fx = np.array([1.0, 1.0, 1.0])
    u = np.array([[9.0], [8.0], [7.0]])
    fu = np.array([0.5, 1.0, 2.0])
    better = de.select(x, fx, u, fu)
    assert better.tolist() == [True, False, False]
    assert x.ravel().tolist() == [9.0, 1.0, 2.0]
    assert fx.tolist() == [0.5, 1.0, 1.0]


def test_schedule_linear_from_initial_to_final() -> None:
    assert harmony.schedule(0, 400, (0.8, 1.0), (0.1, 0.9)) == (0.8, 0.1)
    h, p = harmony.schedule(200, 400, (0.8, 1.0), (0.1, 0.9))
    assert h == pytest.approx(0.9) and p == pytest.approx(0.5)
    h, p = harmony.schedule(100, 400, (0.8, 1.0), (0.1, 0.9))
    assert h == pytest.approx(0.85) and p == pytest.approx(0.3)
    h, p = harmony.schedule(399, 400, (0.8, 1.0), (0.1, 0.9))
    assert h == pytest.approx(0.8 + 0.2 * 399 / 400) and p == pytest.approx(0.1 + 0.8 * 399 / 400)
    h, p = harmony.schedule(np.arange(0, 400, 100), 400, (0.8, 1.0), (0.1, 0.9))  # a block of generations at once
    assert h == pytest.approx([0.8, 0.85, 0.9, 0.95]) and p == pytest.approx([0.1, 0.3, 0.5, 0.7])


def test_improvise_by_hand() -> None:
    memory = np.array([[1, 1, 0, 0], [0, 0, 1, 1], [1, 0, 1, 0]], dtype=bool)
    best = np.array([1, 1, 1, 1], dtype=bool)
    count, d = 2, 4
    pick = [0.5, 0.1]  # members floor(0.5*3)=1 and floor(0.1*3)=0
    consider = [[0.1, 0.9, 0.1, 0.1], [0.9, 0.9, 0.1, 0.1]]  # < HMCR=0.8 -> from memory
    bits = [[0.9, 0.2, 0.9, 0.9], [0.2, 0.7, 0.9, 0.9]]  # random bit = (u < 0.5)
    pitch = [[0.9, 0.0, 0.1, 0.9], [0.0, 0.0, 0.9, 0.0]]  # < PAR=0.3 -> best's bit (memory bits only)
    uni = np.concatenate([pick, np.ravel(consider), np.ravel(bits), np.ravel(pitch)])
    assert uni.size == harmony.n_uniforms(count, d)
    new = harmony.improvise_from_uniforms(memory, best, 0.8, 0.3, uni, count)
    # harmony 0 from member 1 = [0,0,1,1]: bit0 memory 0 (pitch 0.9: keep) -> 0; bit1 random 0.2 -> 1;
    #   bit2 memory 1 (pitch 0.1 -> best 1) -> 1; bit3 memory 1 -> 1
    # harmony 1 from member 0 = [1,1,0,0]: bit0 random 0.2 -> 1 (pitch ignored: not from memory);
    #   bit1 random 0.7 -> 0; bit2 memory 0 (pitch 0.9: keep) -> 0; bit3 memory 0, pitch 0.0 -> best 1
    assert new.astype(int).tolist() == [[0, 1, 1, 1], [1, 0, 0, 1]]


def test_improvise_rates() -> None:
    memory = np.zeros((10, 50), dtype=bool)
    best = np.ones(50, dtype=bool)
    rng = np.random.default_rng(2)
    new = harmony.improvise(memory, best, 1.0, 0.0, 200, rng)
    assert not new.any()  # all from an all-zero memory, no pitch adjustment
    new = harmony.improvise(memory, best, 1.0, 1.0, 200, rng)
    assert new.all()  # every memory bit pitch-adjusted to the best's
    new = harmony.improvise(memory, best, 0.0, 1.0, 400, rng)
    assert abs(new.mean() - 0.5) < 0.02  # all random fair bits
    new = harmony.improvise(memory, best, 0.8, 0.5, 400, rng)
    # P(1) = (1 - HMCR) * 0.5 + HMCR * PAR = 0.1 + 0.4
    assert abs(new.mean() - 0.5) < 0.02
    new = harmony.improvise(memory, best, 0.8, 0.0, 400, rng)
    assert abs(new.mean() - 0.1) < 0.01


def test_update_memory_replaces_worst_by_better() -> None:
    memory = np.array([[1, 0], [0, 1], [1, 1]], dtype=bool)
    fit = np.array([3.0, 1.0, 2.0])
    new = np.array([[0, 0], [1, 0]], dtype=bool)
    nf = np.array([2.5, 5.0])
    entered = harmony.update_memory(memory, fit, new, nf)
    assert entered == 1
    # [0,0] (2.5) replaced the worst [1,0] (3.0); [1,0] (5.0) is worse than all
    rows = {tuple(r) for r in memory.astype(int).tolist()}
    assert rows == {(0, 0), (0, 1), (1, 1)}
    assert sorted(fit.tolist()) == [1.0, 2.0, 2.5]
    # a tie does not replace
    entered = harmony.update_memory(memory, fit, np.array([[1, 0]], dtype=bool), np.array([2.5]))
    assert entered == 0


def test_update_memory_equals_one_by_one() -> None:
    rng = np.random.default_rng(4)
    for _ in range(20):
        mem = rng.random((6, 5)) < 0.5
        fit = rng.random(6)
        new = rng.random((6, 5)) < 0.5
        nf = rng.random(6)
        m1, f1 = mem.copy(), fit.copy()
        harmony.update_memory(m1, f1, new, nf)
        m2, f2 = mem.copy(), fit.copy()
        for h, f in zip(new, nf):  # Step 3 of the paper, one harmony at a time
            w = int(np.argmax(f2))
            if f < f2[w]:
                m2[w], f2[w] = h, f
        assert sorted(f1.tolist()) == sorted(f2.tolist())
        assert sorted(map(tuple, m1.tolist())) == sorted(map(tuple, m2.tolist()))


def test_trial_maker_block_plan_equals_generation_by_generation() -> None:
    """A plan over a block of generations gives, row by row, the one-generation trials."""
    rng = np.random.default_rng(6)
    n, d, blocks = 7, 9, 5
    lo = np.full(d, -1.0)
    hi = np.full(d, 2.0)
    uni = rng.random((blocks, de.TrialMaker.n_uniforms(n, d) + 3))  # extra columns are ignored
    xs = [rng.uniform(-1, 2, (n, d)) for _ in range(blocks)]
    block = de.TrialMaker(n, d, lo, hi, 0.7, 0.4, block=blocks)
    assert block.plan(uni.copy()) == blocks
    one = de.TrialMaker(n, d, lo, hi, 0.7, 0.4)
    for k in range(blocks):
        got = block.make(xs[k], k).copy()
        ref = one(xs[k], uni[k, : de.TrialMaker.n_uniforms(n, d)].copy())
        np.testing.assert_array_equal(got, ref)
        # and by hand from the pure functions
        keys = uni[k, : n * n].reshape(n, n).copy()
        idx = de.donors_from_keys(keys)
        take = de.crossover_mask(uni[k, n * n : n * (n + d)].reshape(n, d), uni[k, n * (n + d) : n * (n + d + 1)], 0.4)
        np.testing.assert_array_equal(got, de.reflect(np.where(take, de.mutate(xs[k], idx, 0.7), xs[k]), lo, hi))
    with pytest.raises(ValueError):
        block.plan(rng.random((blocks + 1, de.TrialMaker.n_uniforms(n, d))))


def test_improviser_block_equals_improvise_from_uniforms() -> None:
    rng = np.random.default_rng(8)
    hms, d, count, blocks = 6, 11, 9, 4
    uni = rng.random((blocks, harmony.n_uniforms(count, d)))
    hmcr = np.array([0.8, 0.85, 0.95, 1.0])
    par = np.array([0.1, 0.4, 0.7, 0.9])
    imp = harmony.Improviser(hms, d, count, block=blocks)
    assert imp.plan(uni, hmcr, par) == blocks
    for k in range(blocks):
        memory = rng.random((hms, d)) < 0.5
        best = rng.random(d) < 0.5
        got = imp.make(memory, best, k).copy()
        ref = harmony.improvise_from_uniforms(memory, best, hmcr[k], par[k], uni[k], count)
        np.testing.assert_array_equal(got, ref)


def test_update_memory_no_entry_leaves_memory_untouched() -> None:
    memory = np.array([[1, 0], [0, 1]], dtype=bool)
    fit = np.array([1.0, 2.0])
    entered = harmony.update_memory(memory, fit, np.array([[1, 1], [0, 0]], dtype=bool), np.array([2.0, 3.0]))
    assert entered == 0
    assert memory.astype(int).tolist() == [[1, 0], [0, 1]] and fit.tolist() == [1.0, 2.0]
    # a NaN newcomer never enters, a better one does
    entered = harmony.update_memory(memory, fit, np.array([[1, 1], [0, 0]], dtype=bool), np.array([np.nan, 0.5]))
    assert entered == 1
    assert sorted(fit.tolist()) == [0.5, 1.0]
