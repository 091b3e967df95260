"""Model: prediction formula, free run, the streamid.model/1 JSON file and its checks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import DataError, ModelFormatError


def _model() -> Model:
    rng = np.random.default_rng(0)
    regs = (Regressor("y", 0, 1), Regressor("u", 0, 1), Regressor("u", 1, 3))
    return Model(
        regressors=regs,
        centres=rng.uniform(-1, 1, (4, 3)),
        widths=rng.uniform(0.5, 2, 4),
        weights=rng.normal(size=4) * 0.3,
        normalisation=Normalisation((0.0, -2.0), (10.0, 2.0), -5.0, 5.0),
        input_names=("a", "b"),
        output_name="out",
        metrics={"fitness": 1.5},
        window={"n_samples": 100},
    )


def _predict_from_json(doc: dict, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """What a reader with only numpy and the README's formula would write."""
    nz = doc["normalisation"]
    un = 2 * (u - np.array(nz["u_low"])) / (np.array(nz["u_high"]) - np.array(nz["u_low"])) - 1
    yn = 2 * (y - nz["y_low"]) / (nz["y_high"] - nz["y_low"]) - 1
    L = doc["max_lag"]
    out = y.copy()
    c, s, w = np.array(doc["centres"]), np.array(doc["widths"]), np.array(doc["weights"])
    for t in range(L, len(y)):
        r = np.array([(yn if g["signal"] == "y" else un[:, g["index"]])[t - g["lag"]] for g in doc["regressors"]])
        phi = np.exp(-((r - c) ** 2).sum(axis=1) / (2 * s**2))
        out[t] = (phi @ w + 1) * (nz["y_high"] - nz["y_low"]) / 2 + nz["y_low"]
    return out


def test_osa_prediction_reproducible_from_the_file_alone() -> None:
    m = _model()
    rng = np.random.default_rng(1)
    u = np.column_stack([rng.uniform(0, 10, 50), rng.uniform(-2, 2, 50)])
    y = rng.uniform(-5, 5, 50)
    doc = json.loads(m.to_json())
    assert doc["format"] == "streamid.model/1"
    assert [r["name"] for r in doc["regressors"]] == ["out(t-1)", "a(t-1)", "b(t-3)"]
    np.testing.assert_allclose(m.predict_osa(u, y), _predict_from_json(doc, u, y), rtol=1e-12)


def test_a_long_record_is_predicted_in_blocks_like_at_once() -> None:
    """predict_osa works through OSA_BLOCK_ROWS rows at a time (bounded memory); the rows across every block
    boundary come out as the formula gives them, and as one matrix over the whole record does."""
    from streamid.model.narx import OSA_BLOCK_ROWS

    m = _model()
    rng = np.random.default_rng(2)
    n = 2 * OSA_BLOCK_ROWS + 777
    u = np.column_stack([rng.uniform(0, 10, n), rng.uniform(-2, 2, n)])
    y = rng.uniform(-5, 5, n)
    got = m.predict_osa(u, y)
    r, _ = m.regressor_rows(u, y)  # the whole record at once
    whole = m.normalisation.y_inverse(m._phi(r) @ m.weights)
    np.testing.assert_allclose(got[m.max_lag :], whole, rtol=1e-13, atol=1e-12)
    edges = [t for b in (OSA_BLOCK_ROWS, 2 * OSA_BLOCK_ROWS) for t in range(b - 2, b + m.max_lag + 2)]
    doc = json.loads(m.to_json())
    for t in edges:  # the formula written out, on the rows next to each block boundary
        lo = t - m.max_lag
        np.testing.assert_allclose(got[t], _predict_from_json(doc, u[lo : t + 1], y[lo : t + 1])[-1], rtol=1e-12)


def test_the_memory_of_a_prediction_does_not_grow_with_the_record() -> None:
    """A 30-lag, 30-neuron model: doubling the record from 262,144 samples adds only its own few arrays to the
    traced peak of numpy's allocations (measured: +6 MB), not the ~1 KB a row that its regressors and activations
    took at once (+260 MB before predict_osa worked in blocks of OSA_BLOCK_ROWS)."""
    import tracemalloc

    from streamid.model.narx import OSA_BLOCK_ROWS

    rng = np.random.default_rng(3)
    regs = tuple(Regressor("y", 0, k) for k in range(1, 16)) + tuple(Regressor("u", 0, k) for k in range(1, 16))
    m = Model(regressors=regs, centres=rng.uniform(-1, 1, (30, 30)), widths=rng.uniform(0.5, 2, 30),
              weights=rng.normal(size=30) * 0.1, normalisation=Normalisation((-1.0,), (1.0,), -1.0, 1.0))
    n = 4 * OSA_BLOCK_ROWS
    peaks = []
    for rows in (n, 2 * n):
        u, y = rng.uniform(-1, 1, (rows, 1)), rng.uniform(-1, 1, rows)
        tracemalloc.start()
        try:
            m.predict_osa(u, y)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] - peaks[0] < 64 * n, peaks  # a few float64 arrays of the record's length, no more


def test_free_run_equals_osa_fed_with_its_own_outputs() -> None:
    m = _model()
    rng = np.random.default_rng(2)
    u = np.column_stack([rng.uniform(0, 10, 40), rng.uniform(-2, 2, 40)])
    y0 = rng.uniform(-5, 5, 40)
    sim = m.simulate(u, y0[: m.max_lag])
    assert sim.shape == (40,)
    assert sim[: m.max_lag].tolist() == y0[: m.max_lag].tolist()
    # a free run is a fixed point of OSA prediction: predicting from the simulated outputs returns them
    np.testing.assert_allclose(m.predict_osa(u, sim), sim, rtol=1e-11, atol=1e-11)
    # a full-length y_init is accepted and only its start used
    np.testing.assert_allclose(m.simulate(u, y0), sim)


def test_json_round_trip_and_lags() -> None:
    m = _model()
    m2 = Model.from_json(m.to_json())
    assert m2.regressors == m.regressors
    np.testing.assert_array_equal(m2.centres, m.centres)
    np.testing.assert_array_equal(m2.weights, m.weights)
    assert m2.normalisation == m.normalisation
    assert m2.lags == {"y": [1], "u": [[1], [3]]} == m.lags
    assert m2.max_lag == 3
    assert m2.metrics == {"fitness": 1.5} and m2.window == {"n_samples": 100}


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda d: d.update(format="streamid.model/9"), "format"),
        (lambda d: d["weights"].__setitem__(0, float("nan")), "finite"),
        (lambda d: d.update(widths=d["widths"][:2]), "shape"),
        (lambda d: d.pop("centres"), "missing"),
        (lambda d: d["regressors"].__setitem__(0, {"signal": "z", "index": 0, "lag": 1}), "signal"),
        (lambda d: d["normalisation"].update(y_high=-10.0), "high > low"),
    ],
)
def test_bad_documents_raise_model_format_error(mutate, match) -> None:
    d = json.loads(_model().to_json())
    mutate(d)
    text = json.dumps(d)  # NaN allowed by json.dumps: the reader must refuse it
    with pytest.raises(ModelFormatError, match=match):
        Model.from_json(text)


def test_not_json_and_not_object() -> None:
    with pytest.raises(ModelFormatError, match="JSON"):
        Model.from_json("{nope")
    with pytest.raises(ModelFormatError, match="object"):
        Model.from_json("[1, 2]")


def test_a_model_never_holds_nan() -> None:
    m = _model()
    with pytest.raises(ModelFormatError, match="finite"):
        Model(m.regressors, m.centres, m.widths, np.array([1.0, np.inf, 0.0, 0.0]), m.normalisation)
    with pytest.raises(ModelFormatError, match="finite"):
        m.with_metrics(r2=float("nan"))
    with pytest.raises(ModelFormatError, match="> 0"):
        Model(m.regressors, m.centres, -m.widths, m.weights, m.normalisation)


def test_prediction_input_errors() -> None:
    m = _model()
    with pytest.raises(DataError, match="2 input"):
        m.predict_osa(np.zeros((10, 3)), np.zeros(10))
    with pytest.raises(DataError, match="finite"):
        m.predict_osa(np.full((10, 2), np.nan), np.zeros(10))
    with pytest.raises(DataError, match="at least max_lag"):
        m.simulate(np.zeros((10, 2)), [1.0])
    with pytest.raises(DataError, match="at least"):
        m.predict_osa(np.zeros((3, 2)), np.zeros(3))


def test_lags_are_written_one_way_with_signal_names() -> None:
    from streamid.model.regressors import format_lags

    assert format_lags("force_N", [1, 2], ["velocity_cm_s"], [[1, 2, 3]]) == "force_N(t-1,t-2) velocity_cm_s(t-1..t-3)"
    assert format_lags("y", [1, 2], ["u"], [[1, 2, 3, 6, 7]]) == "y(t-1,t-2) u(t-1..t-3,t-6,t-7)"
    assert format_lags("y", [], ["a", "b"], [[], [4]]) == "b(t-4)"
    assert format_lags("y", [], ["u"], [[]]) == "(no regressors)"
    assert _model().lags_text() == "out(t-1) a(t-1) b(t-3)"


def test_print_and_summary_are_short_and_readable() -> None:
    m = _model().with_metrics(r2_osa_est=0.99, r2_osa_val=0.98, r2_fr_est=0.97, r2_fr_val=0.9612)
    text = m.summary()
    assert str(m) == text
    assert len(text.splitlines()) <= 8 and "[[" not in text and "array(" not in text
    for part in ("a, b -> out", "out(t-1) a(t-1) b(t-3)", "4 Gaussian neurons", "free run est 0.9700 val 0.9612",
                 "fitness     1.5", "100 samples"):
        assert part in text, part
    assert repr(m).startswith("<Model out = F[out(t-1) a(t-1) b(t-3)], 4 neurons") and len(repr(m)) < 200


def test_save_and_load_round_trip_and_name_a_bad_file(tmp_path) -> None:
    m = _model()
    path = m.save(tmp_path / "m.json")
    back = Model.load(path)
    assert back.lags == m.lags and np.array_equal(back.centres, m.centres) and back.metrics == m.metrics
    assert not list(tmp_path.glob(".*.tmp"))
    wrapped = tmp_path / "update.json"  # a daemon's model-update document is read through its "model" field
    wrapped.write_text(json.dumps({"format": "streamid.model-update/1", "model": m.to_dict()}), encoding="utf-8")
    assert Model.load(wrapped).lags_text() == m.lags_text()
    with pytest.raises(ModelFormatError, match="cannot read .*missing.json"):
        Model.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json", encoding="utf-8")
    with pytest.raises(ModelFormatError, match="bad.json.*must be JSON"):
        Model.load(bad)


@pytest.mark.parametrize("k, M", [(1, 1), (3, 4), (9, 30)])
def test_the_compiled_exponents_are_the_numpy_loop_s_bits(k: int, M: int) -> None:
    # only subtractions, products, sums and one division, each correctly rounded in both (no fused multiply-add):
    # the same bits on any IEEE machine, so a one-step prediction's figures are those recorded before the kernel
    from streamid.model.kernels import scaled_distances

    rng = np.random.default_rng(k * 100 + M)
    r, c, w = rng.normal(size=(257, k)), rng.normal(size=(M, k)), rng.uniform(0.05, 3.0, M)
    d2 = np.zeros((257, M))
    for j in range(k):  # the loop Model._phi ran before
        d2 += np.square(r[:, j : j + 1] - c[None, :, j])
    expected = d2 / -(2.0 * w**2)
    got = np.empty((257, M))
    scaled_distances(r, c, -(2.0 * w**2), got)
    assert np.array_equal(got, expected)
