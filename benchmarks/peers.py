"""Peer tools fitted on the same data in the same run: SysIdentPy FROLS and MetaMSS.

Only ``streamid bench --peers`` uses this module; it needs the ``peers`` extra
(``pip install '.[peers]'``, which installs SysIdentPy).  Both peers fit
polynomial NARX models (SysIdentPy's ``model_type="NARMAX"`` with ordinary least
squares has no noise terms, i.e. it is a NARX model) on the estimation part and
are scored by free-run R^2 on the validation part, started from the first
``max_lag`` measured validation samples, exactly like streamid's own models.

Each peer runs on the data as measured ("raw", as a SysIdentPy user would give
them) and, where it matters, scaled to [-1, 1] with the estimation min/max as
streamid does: FROLS' term ranking is not invariant to an affine rescaling (on
the MR damper scaling moved its lag-5 FR R^2 from 0.979 to 0.959; on the
reactor, whose output is ~3e4 and input ~1e-2, raw data leave it 2 terms).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from streamid.engine.validation import r2

__all__ = ["PeerFit", "fit_frols", "fit_metamss", "bench"]


@dataclass(frozen=True)
class PeerFit:
    tool: str
    seconds: float
    r2_fr_val: float
    n_terms: int


def _columns(u_est: np.ndarray, y_est: np.ndarray, u_val: np.ndarray, y_val: np.ndarray, scale: bool) -> list[np.ndarray]:
    """Column arrays for SysIdentPy, optionally scaled to [-1, 1] with the estimation min/max."""
    u_est, u_val = (np.asarray(a, dtype=np.float64).reshape(len(a), -1) for a in (u_est, u_val))
    y_est, y_val = (np.asarray(a, dtype=np.float64).reshape(-1, 1) for a in (y_est, y_val))
    if not scale:
        return [u_est, y_est, u_val, y_val]
    lo_u, span_u = u_est.min(axis=0), np.ptp(u_est, axis=0)
    lo_y, span_y = y_est.min(), np.ptp(y_est)
    return [2 * (u_est - lo_u) / span_u - 1, 2 * (y_est - lo_y) / span_y - 1,
            2 * (u_val - lo_u) / span_u - 1, 2 * (y_val - lo_y) / span_y - 1]


def _free_run_r2(model: object, u_val: np.ndarray, y_val: np.ndarray, periodic: bool = False) -> float:
    max_lag = int(model.max_lag)  # type: ignore[attr-defined]
    if periodic:  # one steady-state period: simulate two, score the second (the first warms up)
        n = len(y_val)
        yhat = np.asarray(model.predict(X=np.vstack([u_val, u_val]), y=y_val[:max_lag])).ravel()  # type: ignore[attr-defined]
        return r2(y_val.ravel(), yhat[n : 2 * n])
    yhat = np.asarray(model.predict(X=u_val, y=y_val[:max_lag])).ravel()  # type: ignore[attr-defined]
    return r2(y_val.ravel()[max_lag:], yhat[max_lag : len(y_val)])


def fit_frols(
    u_est: np.ndarray, y_est: np.ndarray, u_val: np.ndarray, y_val: np.ndarray, *, max_lag: int, degree: int = 3,
    n_info_values: int = 15, scale: bool = False, periodic: bool = False,
) -> PeerFit:
    """SysIdentPy FROLS polynomial NARX, terms chosen by AIC among the first ``n_info_values``."""
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    ue, ye, uv, yv = _columns(u_est, y_est, u_val, y_val, scale)
    t0 = time.perf_counter()
    model = FROLS(
        order_selection=True, n_info_values=n_info_values, ylag=max_lag, xlag=max_lag, info_criteria="aic",
        estimator=LeastSquares(), basis_function=Polynomial(degree=degree), model_type="NARMAX",
    )
    model.fit(X=ue, y=ye)
    seconds = time.perf_counter() - t0
    return PeerFit(f"SysIdentPy FROLS deg {degree} lag {max_lag} ({'scaled' if scale else 'raw'}, {n_info_values} cand.)", seconds, _free_run_r2(model, uv, yv, periodic),
                   len(model.final_model))


def fit_metamss(
    u_est: np.ndarray, y_est: np.ndarray, u_val: np.ndarray, y_val: np.ndarray, *, max_lag: int, degree: int = 2,
    seed: int = 0, scale: bool = False,
) -> PeerFit:
    """SysIdentPy MetaMSS (binary PSO-GSA structure selection) with the settings of its documentation example."""
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import MetaMSS
    from sysidentpy.parameter_estimation import LeastSquares

    ue, ye, uv, yv = _columns(u_est, y_est, u_val, y_val, scale)
    t0 = time.perf_counter()
    model = MetaMSS(
        basis_function=Polynomial(degree=degree), norm=-2, xlag=max_lag, ylag=max_lag, k_agents_percent=2,
        estimate_parameter=True, maxiter=30, n_agents=10, p_value=0.05, loss_func="metamss_loss",
        estimator=LeastSquares(), model_type="NARMAX", random_state=seed,
    )
    model.fit(X=ue, y=ye)
    seconds = time.perf_counter() - t0
    return PeerFit(f"SysIdentPy MetaMSS deg {degree} lag {max_lag} ({'scaled' if scale else 'raw'})", seconds, _free_run_r2(model, uv, yv),
                   len(model.final_model))


#: (data set, loader, peers to run as (label, fit function, keyword arguments)).
def _cases(options: Any) -> list[tuple[str, Callable[[], tuple[np.ndarray, ...]], list[tuple[Callable[..., PeerFit], dict[str, Any]]]]]:
    from benchmarks.engine_cases import mr_damper_data, piezo_data, reactor_data

    frols_lags = (5,) if options.quick else (5, 7)
    mr: list[tuple[Callable[..., PeerFit], dict[str, Any]]] = [
        (fit_frols, {"max_lag": lag, "n_info_values": 15}) for lag in frols_lags
    ]
    if not options.quick:
        mr.append((fit_frols, {"max_lag": 5, "n_info_values": 40}))
        mr.append((fit_frols, {"max_lag": 5, "n_info_values": 15, "scale": True}))
        mr.append((fit_metamss, {"max_lag": 5, "degree": 2, "seed": options.seed, "scale": True}))
    return [
        ("MR damper (real)", mr_damper_data, mr),
        ("piezo P-885 (real)", piezo_data, [(fit_frols, {"max_lag": 5, "n_info_values": 15})]),
        ("reactor (sim)", lambda: reactor_data(options.seed),
         [(fit_frols, {"max_lag": 2, "n_info_values": 15}), (fit_frols, {"max_lag": 2, "n_info_values": 15, "scale": True}),
          (fit_metamss, {"max_lag": 2, "degree": 2, "seed": options.seed, "scale": True})]),
    ]


def bench(options: Any) -> Iterator[Any]:
    """``streamid bench --peers`` provider: the same data sets fitted by SysIdentPy.

    FROLS is deterministic, so its figures are the median of up to three timed
    repetitions of the same fit; MetaMSS is seeded with ``options.seed``.
    """
    from benchmarks.kit import Measurement

    try:
        import sysidentpy  # noqa: F401
    except ImportError as exc:
        raise ImportError("the peers need SysIdentPy: pip install '.[peers]'") from exc
    repeat = 1 if options.quick else min(options.repeat, 3)
    for name, load, peers in _cases(options):
        u_est, y_est, u_val, y_val = load()
        for fit, kwargs in peers:
            fits = [fit(u_est, y_est, u_val, y_val, **kwargs) for _ in range(repeat)]
            tool = fits[0].tool
            note = f"{fits[0].n_terms} terms"
            yield Measurement("peers", f"{name}: {tool}", "fit time", "s", tuple(f.seconds for f in fits), note)
            yield Measurement("peers", f"{name}: {tool}", "FR R2 val", "", tuple(f.r2_fr_val for f in fits), note)
