"""A model's short readable description (``print(model)``): signals with their lags, neurons, metrics."""

from __future__ import annotations

from typing import Any

from streamid.model.regressors import format_lags

__all__ = ["describe"]


def describe(model: Any) -> str:
    """The lines of :meth:`Model.summary <streamid.model.narx.Model.summary>` (``model`` a Model: read, not imported)."""
    lines = [
        f"RBF-NARX model {', '.join(model.input_names)} -> {model.output_name}",
        f"  regressors  {model.lags_text()}  ({len(model.regressors)} terms, max lag {model.max_lag})",
        f"  network     {model.neurons} Gaussian neurons" + (" and a linear part" if model.linear is not None else ""),
    ]
    if model.linear_regressors is not None:
        ly = [r.lag for r in model.linear_regressors if r.signal == "y"]
        lu = [[r.lag for r in model.linear_regressors if r.signal == "u" and r.index == i] for i in range(model.n_inputs)]
        lines.append(f"  linear part {format_lags(model.output_name, ly, model.input_names, lu)}  "
                     f"({len(model.linear_regressors)} terms of its own)")
    r2 = {k: model.metrics.get(f"r2_{k}") for k in ("osa_est", "fr_est", "osa_val", "fr_val")}
    if any(isinstance(v, (int, float)) for v in r2.values()):

        def f(v: Any) -> str:
            return f"{v:.4f}" if isinstance(v, (int, float)) else "n/a"

        lines.append(
            f"  R2          one-step-ahead est {f(r2['osa_est'])} val {f(r2['osa_val'])}, "
            f"free run est {f(r2['fr_est'])} val {f(r2['fr_val'])}"
        )
    fit = model.metrics.get("fitness")
    if isinstance(fit, (int, float)):
        lines.append(f"  fitness     {fit:.6g} (one-step-ahead MSE on the estimation data, {model.output_name} units squared)")
    n = model.window.get("n_samples", model.window.get("samples"))
    if isinstance(n, int):
        lines.append(f"  fitted on   {n} samples")
    return "\n".join(lines)
