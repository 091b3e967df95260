"""Turn an identification outcome into the :class:`streamid.viz.reports.UpdateReport` that Rerun draws."""

from __future__ import annotations


import numpy as np

from streamid.model.ensemble import members_of
from streamid.online import Update
from streamid.online.refresh import RefreshOutcome
from streamid.viz.reports import UpdateReport, band_of, first_input_tests

__all__ = ["update_report"]


def update_report(stream: str, up: Update, latency_s: float | None) -> UpdateReport:
    """The drawing of one update (its outcome's ``summary`` must be set)."""
    out, window, version = up.outcome, up.window, up.version
    s = out.summary
    assert s is not None
    n_val = len(out.y_val)
    val_t0 = window.t0_ns + (window.n - n_val) * window.period_ns
    lags = out.model.lags if out.model is not None else {}
    nets = members_of(out.model) if out.model is not None else ()  # an ensemble (streamid.model/3): the mean of its networks
    u_val = np.asarray(out.u_val)
    # an accepted model's band on the held-out part (drawn around its free run), its coverage and domain share there
    band, figures = band_of(out.model, u_val, np.asarray(out.y_val)) if up.accepted and out.model is not None \
        else ({}, {})
    return UpdateReport(
        stream=stream,
        version=version,
        accepted=up.accepted,
        warm=out.warm,
        generations=out.generations,
        window_t0_ns=window.t0_ns,
        window_end_ns=window.t_end_ns,
        period_ns=window.period_ns,
        val_t0_ns=val_t0,
        y_val=np.asarray(out.y_val),
        osa_val=np.asarray(s.osa_val),
        fr_val=np.asarray(s.fr_val),
        u_val=np.asarray(out.u_val)[:, 0] if out.u_val.ndim == 2 else np.asarray(out.u_val),
        input_name=out.input_names[0] if out.input_names else "u",
        output_name=out.output_name,
        fitness=out.fitness,
        correlations=first_input_tests(s.tests),
        lags=lags,
        metrics={**s.metrics, **figures},
        identification_s=out.seconds,
        latency_s=latency_s,
        note=up.reason if up.decision is not None or not up.accepted else "",
        input_names=tuple(out.input_names),
        champion_r2_fr=(out.champion_metrics or {}).get("r2_fr_val") if not up.accepted else None,
        networks=len(nets) or 1,
        combine=getattr(out.model, "combine", "mean"),
        linear_parts=sum(m.linear is not None for m in nets),
        long_linear_order=max((m.linear_order for m in nets), default=0),
        refinement=out.model.metrics.get("refinement") if out.model is not None else None,
        refreshed_from=out.refreshed_from if isinstance(out, RefreshOutcome) else None,
        **band,
    )

