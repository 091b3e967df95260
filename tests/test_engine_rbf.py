"""RBF network evaluation and least squares against direct formulas and numpy.linalg.lstsq."""

from __future__ import annotations

import numpy as np
import pytest

from streamid.engine.search.batch import BatchEvaluator
from streamid.engine.fit.rbf import activations, fit_weights, rbf_output


def _direct(r: np.ndarray, c: np.ndarray, s: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Eqs. (2)-(3) of the paper, term by term."""
    out = np.zeros(r.shape[0])
    for t in range(r.shape[0]):
        for m in range(c.shape[0]):
            d2 = sum((r[t, i] - c[m, i]) ** 2 for i in range(r.shape[1]))
            out[t] += w[m] * np.exp(-d2 / (2 * s[m] ** 2))
    return out


def test_rbf_output_matches_formula() -> None:
    rng = np.random.default_rng(0)
    r = rng.uniform(-1, 1, (30, 3))
    c = rng.uniform(-2, 2, (4, 3))
    s = rng.uniform(0.3, 2, 4)
    w = rng.normal(size=4)
    np.testing.assert_allclose(rbf_output(r, c, s, w), _direct(r, c, s, w), rtol=1e-12, atol=1e-14)


def _problem(seed: int, n: int = 200, d: int = 8, m: int = 6, p: int = 7):
    rng = np.random.default_rng(seed)
    R = rng.uniform(-1, 1, (n, d))
    y = np.sin(2 * R[:, 0]) + R[:, 3] * R[:, 1] + 0.05 * rng.normal(size=n)
    masks = rng.random((p, d)) < 0.4
    masks[0] = False  # an empty mask: every activation is 1
    masks[1, :] = True
    centres = rng.uniform(-1.5, 1.5, (p, m, d))
    widths = rng.uniform(0.4, 3.0, (p, m))
    return R, y, masks, centres, widths


def test_batched_activations_match_direct() -> None:
    R, y, masks, centres, widths = _problem(1)
    ev = BatchEvaluator(R, y, 6, 7)
    phi = ev.activations_into(masks, centres, widths).copy()
    for i in range(masks.shape[0]):
        cols = np.flatnonzero(masks[i])
        ref = activations(R[:, cols], centres[i][:, cols], widths[i])
        np.testing.assert_allclose(phi[i].T, ref, rtol=1e-10, atol=1e-13)


def test_shared_mask_path_equals_general_path() -> None:
    R, y, masks, centres, widths = _problem(2)
    same = np.broadcast_to(masks[3], masks.shape)
    ev = BatchEvaluator(R, y, 6, 7)
    a = ev.evaluate(same, centres, widths, shared=True)
    b = ev.evaluate(same.copy(), centres, widths, shared=False)
    c = ev.evaluate(same.copy(), centres, widths)
    np.testing.assert_allclose(a, b, rtol=1e-10)
    np.testing.assert_allclose(a, c, rtol=1e-10)


def test_batched_least_squares_matches_lstsq() -> None:
    R, y, masks, centres, widths = _problem(3)
    ev = BatchEvaluator(R, y, 6, 7, ridge=1e-14)
    mse, w = ev.evaluate(masks, centres, widths, return_weights=True)
    for i in range(masks.shape[0]):
        cols = np.flatnonzero(masks[i])
        phi = activations(R[:, cols], centres[i][:, cols], widths[i])
        ref = np.linalg.lstsq(phi, y, rcond=None)[0]
        ref_mse = np.mean((phi @ ref - y) ** 2)
        assert mse[i] == pytest.approx(ref_mse, rel=1e-7)
        if np.linalg.cond(phi) < 1e4:  # well-posed: the weights themselves agree
            np.testing.assert_allclose(w[i], ref, rtol=1e-6, atol=1e-9)


def test_fit_weights_matches_lstsq() -> None:
    rng = np.random.default_rng(4)
    phi = rng.random((100, 5))
    y = rng.normal(size=100)
    np.testing.assert_allclose(fit_weights(phi, y, 0.0), np.linalg.lstsq(phi, y, rcond=None)[0], rtol=1e-10)
    # the ridge solves the scaled, augmented problem
    ridge = 1e-3
    s = 1 / np.sqrt((phi**2).sum(axis=0))
    a = np.vstack([phi * s, np.sqrt(ridge) * np.eye(5)])
    z = np.linalg.lstsq(a, np.concatenate([y, np.zeros(5)]), rcond=None)[0]
    np.testing.assert_allclose(fit_weights(phi, y, ridge), z * s, rtol=1e-10)
    # nearly collinear columns and the search's ridge: the QR (every column regularised) is the SVD's solution
    near = np.hstack([phi, phi[:, :2] + 1e-7 * rng.normal(size=(100, 2))])
    s = 1 / np.sqrt((near**2).sum(axis=0))
    a = np.vstack([near * s, np.sqrt(1e-10) * np.eye(7)])
    z = np.linalg.lstsq(a, np.concatenate([y, np.zeros(7)]), rcond=None)[0]
    np.testing.assert_allclose(fit_weights(near, y, 1e-10), z * s, rtol=1e-6)


def test_dead_neuron_gets_zero_weight_and_finite_fitness() -> None:
    R, y, masks, centres, widths = _problem(5, p=2)
    masks[:] = True
    centres[:, 0, :] = 4.0  # far from every sample...
    widths[:, 0] = 0.01  # ...and narrow: exp underflows to exactly 0
    ev = BatchEvaluator(R, y, 6, 2)
    mse, w = ev.evaluate(masks, centres, widths, return_weights=True)
    assert np.all(np.isfinite(mse)) and np.all(np.isfinite(w))
    assert np.all(w[:, 0] == 0.0)
    cols = np.arange(R.shape[1])
    phi = activations(R, centres[0][:, cols], widths[0])
    assert np.all(phi[:, 0] == 0.0)
    wf = fit_weights(phi, y, 1e-10)
    assert np.all(np.isfinite(wf)) and wf[0] == 0.0


def test_capacity_checked() -> None:
    R, y, masks, centres, widths = _problem(6)
    ev = BatchEvaluator(R, y, 6, 3)
    with pytest.raises(ValueError, match="at most 3"):
        ev.evaluate(masks, centres, widths)


def test_batched_solve_and_its_singular_fallback() -> None:
    from streamid.engine.search.batch import _solve

    rng = np.random.default_rng(11)
    a = rng.standard_normal((4, 5, 5))
    a = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(5)
    b = rng.standard_normal((4, 5, 1))
    np.testing.assert_allclose(_solve(a, b), np.linalg.solve(a, b), rtol=1e-10)
    a[2] = 0.0  # exactly singular: the batch falls back to per-member least squares
    a[2, 0, 0] = 1.0
    z = _solve(a, b)
    assert np.all(np.isfinite(z))
    for i in (0, 1, 3):
        np.testing.assert_allclose(z[i], np.linalg.solve(a[i], b[i]), rtol=1e-10)
    np.testing.assert_allclose(z[2, :, 0], np.linalg.lstsq(a[2], b[2, :, 0], rcond=None)[0])


def test_batched_activations_with_empty_and_full_masks() -> None:
    """Packing edge cases: a member with no lag (all activations 1) and one with every lag."""
    R, y, masks, centres, widths = _problem(3)
    masks = masks.copy()
    masks[0] = False
    masks[1] = True
    ev = BatchEvaluator(R, y, 6, 7)
    for m in (masks, masks[:1]):  # several members, and only the empty one
        p = m.shape[0]
        phi = ev.activations_into(m, centres[:p], widths[:p]).copy()
        for i in range(p):
            cols = np.flatnonzero(m[i])
            ref = activations(R[:, cols], centres[i][:, cols], widths[i])
            np.testing.assert_allclose(phi[i].T, ref, rtol=1e-10, atol=1e-13)
    np.testing.assert_array_equal(phi[0], 1.0)


def test_compiled_exp2_is_numpys_to_one_ulp_and_keeps_its_special_values() -> None:
    """The activations' exp2 off AVX-512 (streamid.engine.fit.kernels.exp2_rows): within 1 ulp of numpy's on the
    evaluator's range, exact at integers, 0 below -1022 (numpy: subnormals), inf above 1023, nan kept; only the
    rows asked for are touched, and rows longer than one chunk are done whole."""
    from streamid.engine.fit.kernels import exp2_rows

    rng = np.random.default_rng(7)
    buf = np.empty((3, 5, 2500))
    buf[:] = -rng.random(buf.shape) * 80.0
    buf[1, 2, :12] = [0.0, -1.0, -0.5, 0.5, 3.0, -1021.9, -1022.0, -1030.0, -np.inf, np.nan, 1100.0, np.inf]
    before = buf.copy()
    with np.errstate(over="ignore"):
        want = np.exp2(before[:, 1:4, :])
    exp2_rows(buf, 1, 4)
    got = buf[:, 1:4, :]
    np.testing.assert_array_equal(buf[:, [0, 4], :], before[:, [0, 4], :])  # other rows untouched
    normal = (want >= np.finfo(np.float64).tiny) & np.isfinite(want)
    assert np.max(np.abs(got[normal] - want[normal]) / want[normal]) <= np.finfo(np.float64).eps
    row = got[1, 1]
    assert row[0] == 1.0 and row[1] == 0.5 and row[4] == 8.0  # powers of two exactly
    assert row[7] == 0.0 and row[8] == 0.0 and np.isnan(row[9]) and row[10] == np.inf and row[11] == np.inf
    assert np.all(got[~normal & np.isfinite(before[:, 1:4, :]) & (before[:, 1:4, :] < -1022)] == 0.0)


def test_compiled_gram_is_numpys_product_for_every_block_shape() -> None:
    """The search's Gram off AVX-512 (streamid.engine.fit.kernels.gram_rows): ``ext[:p, :R] @ ext[:p, 1:R].T`` to
    rounding, for every row count (the 2 x 4 blocks' edges), sample counts off the chunk size, and only the first
    ``p`` members written."""
    from streamid.engine.fit.kernels import gram_rows

    rng = np.random.default_rng(11)
    for R in range(2, 12):
        for n in (1, 7, 256, 700):
            ext = rng.standard_normal((4, R + 2, n))
            gb = np.full((4, R, R - 1), -7.0)
            gram_rows(ext, 3, R, gb)
            want = ext[:3, :R] @ ext[:3, 1:R].transpose(0, 2, 1)
            np.testing.assert_allclose(gb[:3], want, rtol=1e-12, atol=1e-12 * n)
            np.testing.assert_array_equal(gb[3], -7.0)
            np.testing.assert_array_equal(gb[:3, 1:], gb[:3, 1:].transpose(0, 2, 1))  # the Gram is symmetric


def test_both_paths_of_the_evaluator_give_the_same_fitness(monkeypatch: pytest.MonkeyPatch) -> None:
    """numpy's path (AVX-512 machines) and the compiled kernels' agree on a batch's fitness and weights, with
    per-member and shared masks."""
    import streamid.engine.fit.rbf as rbf

    rng = np.random.default_rng(5)
    n, D, M, P = 900, 6, 9, 5
    R = rng.standard_normal((n, D))
    y = np.tanh(R[:, 0]) + 0.3 * R[:, 1] * R[:, 2]
    masks = rng.random((P, D)) < 0.6
    masks[:, 0] = True
    centres = rng.standard_normal((P, M, D))
    widths = 0.5 + rng.random((P, M))
    out = {}
    for numpy_path in (True, False):
        monkeypatch.setattr(rbf, "NUMPY_PATH", numpy_path)
        ev = BatchEvaluator(R, y, M, P)
        for shared in (False, True):
            mk = np.repeat(masks[:1], P, axis=0) if shared else masks
            out[numpy_path, shared] = ev.evaluate(mk, centres, widths, return_weights=True, shared=shared)
    for shared in (False, True):
        (m0, w0), (m1, w1) = out[True, shared], out[False, shared]
        assert np.all(m0 > 0)
        np.testing.assert_allclose(m1, m0, rtol=1e-9)
        np.testing.assert_allclose(w1, w0, rtol=1e-6, atol=1e-9)
