"""The RBF network with a direct linear part (CoEAConfig.linear_terms): formula, free run, file format, fit."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from streamid.engine import DEFAULT, identify
from streamid.model import Model
from streamid.engine.choice.scores import group_free_run
from streamid.model.narx import MODEL_FORMAT, MODEL_FORMAT_LINEAR
from streamid.model.regressors import Normalisation, Regressor
from streamid.engine.choice.selection import refit_weights
from streamid.engine.validation import r2
from streamid.errors import ModelFormatError


def _model(linear: bool = True) -> Model:
    rng = np.random.default_rng(0)
    regs = (Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 1), Regressor("u", 1, 3))
    return Model(
        regressors=regs,
        centres=rng.uniform(-1, 1, (4, 4)),
        widths=rng.uniform(0.5, 2, 4),
        weights=rng.normal(size=4) * 0.3,
        normalisation=Normalisation((0.0, -2.0), (10.0, 2.0), -5.0, 5.0),
        input_names=("a", "b"),
        output_name="out",
        linear=np.array([0.3, -0.2, 0.25, -0.1, 0.05]) if linear else None,
    )


def _by_hand(doc: dict, u: np.ndarray, y: np.ndarray, free: bool) -> np.ndarray:
    """The file's formula written out with numpy alone (one-step-ahead, or free run on its own outputs)."""
    nz = doc["normalisation"]
    un = 2 * (u - np.array(nz["u_low"])) / (np.array(nz["u_high"]) - np.array(nz["u_low"])) - 1
    yn = 2 * (y - nz["y_low"]) / (nz["y_high"] - nz["y_low"]) - 1
    L = doc["max_lag"]
    c, s, w = np.array(doc["centres"]), np.array(doc["widths"]), np.array(doc["weights"])
    a = np.array(doc.get("linear", [0.0] * (len(doc["regressors"]) + 1)))
    src = yn.copy()
    for t in range(L, len(y)):
        r = np.array([(src if g["signal"] == "y" else un[:, g["index"]])[t - g["lag"]] for g in doc["regressors"]])
        out = np.exp(-((r - c) ** 2).sum(axis=1) / (2 * s**2)) @ w + r @ a[:-1] + a[-1]
        if free:
            src[t] = out
        else:
            yn[t] = yn[t]  # measured outputs stay
            src = yn
            res = src.copy() if t == L else res
            res[t] = out
    sim = src if free else res
    return (sim + 1) * (nz["y_high"] - nz["y_low"]) / 2 + nz["y_low"]


def _data(n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    return np.column_stack([rng.uniform(0, 10, n), rng.uniform(-2, 2, n)]), rng.uniform(-5, 5, n)


def test_prediction_and_free_run_follow_the_documented_formula() -> None:
    m = _model()
    u, y = _data()
    doc = json.loads(m.to_json())
    assert doc["format"] == MODEL_FORMAT_LINEAR and "linear[j] r_j(t)" in doc["formula"]
    L = m.max_lag
    np.testing.assert_allclose(m.predict_osa(u, y)[L:], _by_hand(doc, u, y, free=False)[L:], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(m.simulate(u, y[:L])[L:], _by_hand(doc, u, y, free=True)[L:], rtol=1e-9, atol=1e-9)
    # the linear part matters: without it the free run differs
    assert not np.allclose(replace(m, linear=None).simulate(u, y[:L]), m.simulate(u, y[:L]))


def test_batched_free_run_mixing_networks_with_and_without_a_linear_part() -> None:
    m, plain = _model(), _model(linear=False)
    m2 = replace(m, linear=np.array([-0.1, 0.2, 0.0, 0.3, -0.2]))
    u, y = _data()
    sims = group_free_run([m, plain, m2], u, y)
    for k, one in enumerate((m, plain, m2)):
        alone = one.normalisation.y(one.simulate(u, y[: one.max_lag]))
        np.testing.assert_allclose(sims[k, one.max_lag :], alone[one.max_lag :], rtol=1e-10, atol=1e-10)


def test_file_format_versions() -> None:
    m = _model()
    back = Model.from_json(m.to_json())
    assert back.linear is not None and np.array_equal(back.linear, m.linear)
    plain = _model(linear=False)
    assert json.loads(plain.to_json())["format"] == MODEL_FORMAT  # no linear part: still the first format
    assert "linear" not in json.loads(plain.to_json()) and Model.from_json(plain.to_json()).linear is None
    odd = {**json.loads(plain.to_json()), "linear": [1.0, 2.0, 3.0, 4.0, 5.0]}  # a /1 document has no linear part
    assert Model.from_dict(odd).linear is None
    doc = json.loads(m.to_json())
    del doc["linear"]
    with pytest.raises(ModelFormatError, match="needs the field 'linear'"):
        Model.from_dict(doc)
    doc = json.loads(m.to_json())
    doc["linear"] = [0.1, 0.2]
    with pytest.raises(ModelFormatError, match="'linear' must have shape \\(5,\\)"):
        Model.from_dict(doc)
    doc["linear"] = [0.1, 0.2, 0.3, float("nan"), 0.0]
    with pytest.raises(ModelFormatError, match="finite"):
        Model.from_dict({**doc, "linear": doc["linear"]})


def _arx(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, n)
    y = np.zeros(n)
    for t in range(2, n):
        y[t] = 1.2 * y[t - 1] - 0.5 * y[t - 2] + 0.4 * u[t - 1] + 0.2 * u[t - 2]
    return u, y


def test_linear_terms_fit_a_near_linear_system_and_refit_keeps_them() -> None:
    u, y = _arx(900, 0)
    cfg = DEFAULT.replace(generations=20, restarts=2, max_lag_cap=0)
    lin = identify(u[:600], y[:600], cfg.replace(linear_terms=True), 0).model
    plain = identify(u[:600], y[:600], cfg.replace(linear_terms=False), 0).model
    assert lin.linear is not None and plain.linear is None
    fr_lin = r2(y[600 + lin.max_lag :], lin.simulate(u[600:], y[600:])[lin.max_lag :])
    fr_plain = r2(y[600 + plain.max_lag :], plain.simulate(u[600:], y[600:])[plain.max_lag :])
    assert fr_lin > 0.9999 and fr_lin > fr_plain
    again = refit_weights(replace(lin, linear=np.zeros_like(lin.linear)), u[:600], y[:600], 1e-10)
    assert again.linear is not None
    # the same fit up to the rows used (the run fits from its candidate lag space's maximum, refit_weights from the model's)
    np.testing.assert_allclose(again.linear, lin.linear, rtol=1e-3, atol=1e-3)


def test_identify_cli_offers_the_linear_part_by_default_reports_it_and_obeys_no_linear(tmp_path: Path) -> None:
    assert DEFAULT.linear_terms is True  # the default since round 11
    u, y = _arx(900, 1)  # a linear plant: the kind with the linear part wins by AIC
    data = tmp_path / "arx.csv"
    np.savetxt(data, np.column_stack([u, y]), delimiter=",", header="volt,pos", comments="", fmt="%.17g")
    mod = tmp_path / "m.json"
    args = [sys.executable, "-m", "streamid", "identify", str(data), "--input", "volt", "--output", "pos", "--generations",
            "5", "--restarts", "2", "--more-restarts", "0", "--no-ensembles",
            "--workers", "1", "--progress", "never", "--model", str(mod)]
    p = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    m = Model.load(mod)
    assert m.linear is not None and m.config["linear_terms"] is True
    assert ("direct linear part a'r + b: kept (every candidate was offered with and without one, the kind chosen by "
            "aic)") in p.stdout
    off = subprocess.run(args + ["--no-linear"], capture_output=True, text=True, timeout=120)
    assert off.returncode == 0, off.stderr
    m = Model.load(mod)
    assert m.linear is None and m.config["linear_terms"] is False and "direct linear part" not in off.stdout
    bad = subprocess.run([sys.executable, "-m", "streamid", "identify", str(data), "--input", "volt", "--output", "pos",
                          "--paper", "--linear"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--linear offers networks with a direct linear part; --paper keeps" in bad.stderr
