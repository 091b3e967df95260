"""Cheaper warm updates: the champion's output weights refreshed by exact blocked least squares between searches.

A champion's structure -- its lags, centres, widths and normalisation -- is what the coevolution
searches for, and it is costly to find; its output weights (the RBF weights and the linear part, with
its constant) are a linear least-squares problem once the structure is fixed.  Between two coevolution
runs an update therefore only re-solves that problem on the newest data: a :class:`RefreshJob`
adds the window's estimation rows not seen yet to the normal equations ``A = sum l^a x x^T``,
``b = sum l^a x y`` (``x`` the row's activations, linear regressors and 1; ``l`` the forgetting factor
per sample, ``exp(-period / memory_s)``: the exponentially weighted recursive least squares, computed
exactly in blocks rather than one rank-one update a sample), and solves them with the engine's Jacobi
scaling and a ridge.  The cost per new sample is one row of activations and its outer product:
microseconds (``streamid bench --only capacity`` measures it).

A refreshed model is a *challenger* like any other: it is judged with the champion on the same
held-out newest part of the window, which it was not fitted on, by the rule of
:mod:`streamid.online.acceptance`, and published with the next version only if it wins.  Its document
says ``"update": "refreshed"`` (``"identified"`` for a coevolution run's model) and which version it
refreshed; its model's metrics say the same.

**The policy** (:class:`RefreshPolicy`, :class:`RefreshTrack`): a coevolution run (warm-started from
the previous final populations) is the next update

* when the output has no champion, or a champion that cannot be refreshed (an ensemble, other signals
  or sample period than the window's, a saved champion whose populations do not fit);
* at once after a drift (the escalated runs of :mod:`streamid.online.drift`), after a failed or
  invalid update, and when the champion fails its re-validation (its free-run or one-step R^2 on the
  newest held-out data below the floors, or a refreshed challenger below them);
* otherwise every ``every`` updates (a run due so waits while a live stream's backlog of windows is worked
  through, each window refreshed in order, and while the caller is loaded, at most ``max_every`` in a row).  ``every`` starts at :attr:`RefreshPolicy.min_every`, doubles
  (up to :attr:`RefreshPolicy.max_every`) each time a coevolution run's challenger loses to the champion
  (``not_better``: the champion keeps winning), and returns to ``min_every`` when a run's challenger is
  accepted or anything above forced a run.

Every other update is a refresh.  Pure computation, no I/O, no clock but ``time.perf_counter`` for the
run's own seconds (as :mod:`streamid.online.update`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from streamid.model import Model
from streamid.engine.fit.rbf import MIN_NORM, activations
from streamid.engine.choice.stability import ar_radius, is_bounded, radius
from streamid.online.head import OutputHead
from streamid.online.refresh_policy import RefreshPolicy
from streamid.online.stream_config import StreamConfig
from streamid.online.summary import summarise
from streamid.online.update import Outcome, StopFlag, Stopped, UpdateJob, champion_figures, signature_of
from streamid.online.update import _unusable as unusable  # the same data checks as a coevolution run's
from streamid.online.window_types import Window

__all__ = ["RefreshPolicy", "NormalEquations", "RefreshJob", "RefreshOutcome", "RefreshTrack", "basis_key",
           "coevolve_reason", "refresh_job", "refreshed_weights"]

#: Largest number of design columns (neurons, linear terms, constant) a refresh solves for: a champion with a long
#: linear part of a high order is re-identified instead (its normal equations would cost ``n p^2`` per window and their
#: saved state ``p^2`` numbers).
MAX_REFRESH_COLUMNS = 64

#: Codes of a coevolution run's decision after which the champion kept winning (the policy backs off).
_KEPT = ("not_better",)
#: Codes of a decision that accepted the challenger.
_WON = ("first", "better", "champion_invalid", "champion_inapplicable", "every")


def basis_key(model: Model) -> str:
    """What a champion's normal equations depend on: its regressors, centres, widths, normalisation, linear terms."""
    h = hashlib.blake2b(digest_size=12)
    h.update(repr((model.regressors, model.linear_regressors, model.linear is None, model.normalisation)).encode())
    for a in (model.centres, model.widths):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def design_columns(model: Model) -> int:
    """Columns of ``model``'s refresh design: a weight per neuron, then the linear part's (with its constant)."""
    if model.linear is None:
        return model.neurons
    return model.neurons + len(model.linear_regressors or model.regressors) + 1


@dataclass(frozen=True, eq=False)
class NormalEquations:
    """The forgetting-weighted normal equations of one champion's output weights (immutable: a job returns new ones).

    ``a`` (p x p) and ``b`` (p,) over the design columns ``[activations, linear regressors, 1]`` (the last two
    only when the champion has a linear part); ``weight`` the sum of the rows' weights (the effective rows);
    ``through_t_ns`` the stream time of the newest row added; ``basis`` the champion's :func:`basis_key`.
    """

    basis: str
    a: np.ndarray
    b: np.ndarray
    weight: float
    through_t_ns: int
    rows: int  # rows added in all (not weighted)


def _design(model: Model, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The refresh's design rows of ``t >= max_lag`` and their normalised targets."""
    r, yn = model.regressor_rows(u, y)
    phi = activations(r, model.centres, model.widths)
    if model.linear is None:
        return phi, yn
    lin = model.linear_rows(u, y)
    return np.hstack([phi, lin, np.ones((phi.shape[0], 1))]), yn


def accumulate(normal: NormalEquations | None, model: Model, u: np.ndarray, y: np.ndarray, t0_ns: int,
               period_ns: int, memory_s: float) -> NormalEquations:
    """``normal`` with the rows of ``u``/``y`` (samples from stream time ``t0_ns``) newer than its ``through_t_ns``.

    The older rows' weights decay by ``exp(-elapsed / memory_s)``; a ``normal`` of another basis is discarded
    (the rows are then all of ``u``/``y``).
    """
    u = u.reshape(u.shape[0], -1)  # (one input may come as a vector)
    key = basis_key(model)
    L, n = model.max_lag, y.shape[0]
    through = t0_ns + (n - 1) * period_ns
    if normal is not None and (normal.basis != key or normal.through_t_ns > through):
        normal = None  # another champion's, or the stream's clock went back (a reset): its rows start again
    first = L  # the first sample whose row is new
    if normal is not None:
        first = max(L, -(-(normal.through_t_ns - t0_ns) // period_ns) + 1)
    if first >= n:  # nothing new
        return normal if normal is not None else NormalEquations(key, np.zeros((0, 0)), np.zeros(0), 0.0, through, 0)
    x, target = _design(model, u[first - L:], y[first - L:])
    lam_log = -(period_ns / 1e9) / memory_s  # log of the per-sample forgetting factor
    k = x.shape[0]
    w = np.exp(lam_log * np.arange(k - 1, -1, -1, dtype=np.float64))  # newest row weight 1
    xw = x * w[:, None]
    a, b = xw.T @ x, xw.T @ target
    weight = float(w.sum())
    rows = k
    if normal is not None and normal.a.shape == a.shape:
        decay = math.exp(lam_log * ((through - normal.through_t_ns) / period_ns))
        a, b = a + decay * normal.a, b + decay * normal.b
        weight += decay * normal.weight
        rows += normal.rows
    return NormalEquations(key, a, b, weight, through, rows)


def refreshed_weights(normal: NormalEquations, ridge: float) -> np.ndarray | None:
    """The weights solving ``normal`` (Jacobi-scaled, ``ridge`` on the unit diagonal); None if not solvable.

    A column whose weighted norm is below the engine's :data:`~streamid.engine.fit.rbf.MIN_NORM` (a neuron where no
    sample is) gets weight 0, as in the search.
    """
    return _solve(normal.a, normal.b, ridge)


def _solve(a: np.ndarray, b: np.ndarray, ridge: float) -> np.ndarray | None:
    """``a w = b`` Jacobi-scaled with ``ridge`` on the unit diagonal (see :func:`refreshed_weights`)."""
    d = np.diag(a)
    if d.size == 0 or not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)):
        return None
    active = d > MIN_NORM**2
    s = np.where(active, 1.0 / np.sqrt(np.where(active, d, 1.0)), 0.0)
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return None
    m = a[np.ix_(idx, idx)] * np.outer(s[idx], s[idx])
    m[np.diag_indices_from(m)] += ridge
    rhs = b[idx] * s[idx]
    try:
        z = scipy.linalg.solve(m, rhs, assume_a="pos", check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return None
    w = np.zeros(d.size)
    w[idx] = z * s[idx]
    return w if np.all(np.isfinite(w)) else None


def own_autoregression(normal: NormalEquations, champion: Model, ridge: float) -> np.ndarray | None:
    """Weights as :func:`refreshed_weights`, with the output terms of the linear part those of the linear part solved
    alone (its own sub-block of the normal equations), when that autoregression is stable; the network's weights,
    the input terms and the constant then solved with it fixed. The engine's rule for a long linear part
    (:mod:`streamid.engine.choice.longlinear`, step 3b), here where the refit's network and linear part split the fit into
    an unstable autoregression. None: not solvable, or the linear part alone unstable too."""
    M = champion.neurons
    regs = champion.linear_regressors if champion.linear_regressors is not None else champion.regressors
    lin = np.arange(M, M + len(regs) + 1)  # the linear part's columns and the constant
    c = _solve(normal.a[np.ix_(lin, lin)], normal.b[lin], ridge)
    if c is None or not radius(regs, c[:-1]) < 1.0:
        return None
    ys = np.array([M + j for j, r in enumerate(regs) if r.signal == "y"], dtype=np.intp)
    rest = np.setdiff1d(np.arange(normal.b.size), ys)
    a_y = c[ys - M]
    z_rest = _solve(normal.a[np.ix_(rest, rest)], normal.b[rest] - normal.a[np.ix_(rest, ys)] @ a_y, ridge)
    if z_rest is None:
        return None
    z = np.zeros(normal.b.size)
    z[ys], z[rest] = a_y, z_rest
    return z


@dataclass(frozen=True, eq=False)
class RefreshOutcome(Outcome):
    """A refresh's :class:`~streamid.online.update.Outcome`, with the normal equations it leaves behind."""

    normal: NormalEquations | None = None
    refreshed_from: int = 0  # the champion's version whose structure was kept


@dataclass(frozen=True, eq=False)
class RefreshJob(UpdateJob):
    """An update that refreshes the champion's weights on the window instead of running the coevolution.

    Taken by :meth:`~streamid.online.OnlineIdentifier.next_job` when :class:`RefreshTrack` says so; ``champion``
    is the model refreshed, ``champion_version`` its version, ``normal`` the equations accumulated so far.
    ``warm_state``/``warm_signature`` pass through unchanged (the next coevolution run starts from them).
    """

    champion_version: int = 0
    normal: NormalEquations | None = None
    policy: RefreshPolicy = RefreshPolicy()

    def run(self, *, stop: StopFlag | None = None, on_generation: Any = None, helper: Any = None) -> Outcome:
        """Refresh and validate (pure; short: ``stop`` is polled once, before it starts, raising
        :class:`~streamid.online.update.Stopped`; ``on_generation`` and ``helper`` are not used)."""
        if stop is not None and stop.is_set():
            raise Stopped
        return refresh_window(self)


def refresh_window(job: RefreshJob) -> Outcome:
    """The body of :meth:`RefreshJob.run`: never raises for bad data (a ``failed`` outcome, ``refresh_failed``)."""
    t_start = time.perf_counter()
    w, cfg, champion = job.window, job.config, job.champion
    output = job.output or w.output_names[0]
    meta = {"number": w.number, "t0_ns": int(w.t0_ns), "t_end_ns": int(w.t_end_ns), "period_ns": int(w.period_ns),
            "n_samples": w.n, "coalesced_before": int(w.coalesced_before), "output": output}
    common: dict[str, Any] = {"window_meta": meta, "output_name": output, "input_names": w.input_names}
    sig = signature_of(w, cfg, output)
    if champion is None or output not in w.output_names or champion.n_inputs != len(w.input_names):
        return Outcome("failed", "the champion cannot be refreshed on this window's signals", "refresh_failed",
                       signature=sig, **common)
    y = np.ascontiguousarray(w.y[:, w.output_names.index(output)])
    n_val = int(round(w.n * cfg.validation_fraction))
    n_est = w.n - n_val
    meta.update(n_estimation=n_est, n_validation=n_val)
    L = champion.max_lag
    if n_est <= L + 2 or n_val <= L + 2:
        return Outcome("failed", f"window too short to refresh a champion of max lag {L}: {n_est} estimation, "
                       f"{n_val} validation samples", "refresh_failed", signature=sig, **common)
    u_est, y_est, u_val, y_val = w.u[:n_est], y[:n_est], w.u[n_est:], y[n_est:]
    why = unusable([(f"input {s!r}", "estimation", u_est[:, i]) for i, s in enumerate(w.input_names)]
                   + [(f"output {output!r}", "estimation", y_est), (f"output {output!r}", "validation", y_val)])
    if why is not None:
        return Outcome("dropped", why, "constant_signal", signature=sig, **common)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        normal = accumulate(job.normal, champion, u_est, y_est, w.t0_ns, w.period_ns, job.policy.memory_s)
        z = refreshed_weights(normal, job.policy.ridge)
    if z is None:
        return Outcome("failed", "the refreshed normal equations could not be solved (not finite or no active "
                       "neuron)", "refresh_failed", signature=sig, **common)
    M = champion.neurons
    kept = {k: v for k, v in champion.metrics.items() if k in ("selection", "long_linear")}
    model = dataclasses.replace(
        champion, weights=z[:M], linear=None if champion.linear is None else z[M:],
        metrics={**kept, "update": "refreshed", "refreshed_from_version": int(job.champion_version),
                 "refreshed_samples": int(normal.rows), "refreshed_weight": round(normal.weight, 1)},
        window={**champion.window, **{k: v for k, v in meta.items() if k != "coalesced_before"}},
    )
    if not is_bounded(model):  # the refit moved a root of the linear part's autoregression out (streamid.engine.choice.stability)
        z2 = own_autoregression(normal, champion, job.policy.ridge)
        if z2 is not None:
            model = dataclasses.replace(model, weights=z2[:M], linear=z2[M:])
    if not is_bounded(model):
        return Outcome("failed", f"the refreshed linear part's autoregression is unstable (largest root "
                       f"{ar_radius(model):.4g}); the coevolution reruns", "refresh_failed", signature=sig, **common)
    # the champion's interval stays (a refresh keeps the structure): calibrating the refreshed weights' own band
    # cost a third of the refreshes a box makes (docs/method.md, "Online"); the next coevolution run calibrates anew
    summary = summarise(model, u_est, y_est, u_val, y_val)
    champ, champ_fr = champion_figures(champion, u_val, y_val)
    return RefreshOutcome(
        "identified", model=model, state=job.warm_state, summary=summary, warm=True, generations=0,
        seconds=time.perf_counter() - t_start, signature=dict(job.warm_signature or sig), u_val=u_val, y_val=y_val,
        champion_metrics=champ, champion_fr_val=champ_fr, t_val_ns=int(w.t0_ns + n_est * w.period_ns),
        normal=normal, refreshed_from=int(job.champion_version), **common)


@dataclass(eq=False)
class RefreshTrack:
    """One output's refresh policy state (mutable, owned by one identifier; see the module docstring)."""

    policy: RefreshPolicy
    every: int = 0  # updates between scheduled coevolution runs (0: not set yet -> min_every)
    due_in: int = 0  # refreshes left before the next scheduled run (0: the next update is a run)
    force: str = ""  # why the next update must be a coevolution run ("" : none)
    normal: NormalEquations | None = None
    refreshed: int = 0  # refreshes run
    refreshes_accepted: int = 0
    identified: int = 0  # coevolution runs
    last: str = ""  # "refreshed" or "identified": the kind of the last finished update
    champion_kind: str = ""  # how the served champion was made
    deferred: int = 0  # scheduled runs deferred in a row (the caller was loaded)
    deferred_total: int = 0
    deferred_backlog: int = 0  # of which behind a live backlog

    def plan(self, *, champion: Model | None, window: Window | None, signature: dict[str, Any] | None,
             champion_signature: dict[str, Any] | None, escalate: bool, failures_in_row: int,
             current: dict[str, Any], min_r2_fr: float, min_r2_osa: float) -> str:
        """Why the next update of this output must be a coevolution run ("" : it is a refresh).

        ``window``/``signature`` None (the status, between windows): the checks that need the window are skipped.
        """
        if not self.policy.enabled:
            return "refreshes disabled"
        if champion is None:
            return "no champion yet"
        if type(champion) is not Model:
            return "the champion is an ensemble (its members share no design)"
        if (p := design_columns(champion)) > MAX_REFRESH_COLUMNS:
            return f"the champion has {p} weights, more than the {MAX_REFRESH_COLUMNS} a refresh solves for"
        if signature is not None and champion_signature is not None and champion_signature != signature:
            return "the window's signals or settings changed"
        if window is not None and champion.window.get("period_ns") not in (None, window.period_ns):
            return "the champion was identified at another sample period"
        if escalate:
            return "drift"
        if failures_in_row:
            return "the last update failed or was invalid"
        fr, osa = current.get("r2_fr_val"), current.get("r2_osa_val")
        if isinstance(fr, float) and isinstance(osa, float) and not (fr >= min_r2_fr and osa >= min_r2_osa):
            return "the champion failed its re-validation"
        if self.force:
            return self.force
        if self.due_in <= 0:
            return f"scheduled (every {self.every or self.policy.min_every} updates)"
        return ""

    def deferrable(self, reason: str, *, backlog: bool = False) -> bool:
        """Whether a run due for ``reason`` may wait (a refresh instead) while the caller is loaded: only a scheduled
        one, at most ``max_every`` updates in a row; behind a live backlog (``backlog``) as long as it lasts."""
        return reason.startswith("scheduled") and (backlog or self.deferred < self.policy.max_every)

    def defer_for_backlog(self, reason: str) -> bool:
        """A scheduled run waits while a live stream's backlog is worked through (refreshes in order, each window
        decided); counted with the other deferrals. The backlog's bound (``max_pending_s``) bounds the wait."""
        if not self.deferrable(reason, backlog=True):
            return False
        self.deferred += 1
        self.deferred_total += 1
        self.deferred_backlog += 1
        return True

    def defer(self, reason: str) -> bool:
        """:meth:`deferrable`, and if so count the deferral (the next update is a refresh)."""
        if not self.deferrable(reason):
            return False
        self.deferred += 1
        self.deferred_total += 1
        return True

    def after(self, *, refresh: bool, code: str, accepted: bool, normal: NormalEquations | None) -> None:
        """Account for a finished update: a refresh's or a coevolution run's decision ``code``."""
        p = self.policy
        if self.every <= 0:
            self.every = p.min_every
        self.last = "refreshed" if refresh else "identified"
        self.force = ""
        if refresh:
            self.refreshed += 1
            self.due_in -= 1
            if normal is not None:
                self.normal = normal
            if accepted:
                self.refreshes_accepted += 1
                self.champion_kind = "refreshed"
            elif code not in _KEPT:  # below the floors, failed: the structure may no longer fit
                self.force = f"a refreshed challenger was refused ({code})"
            return
        self.identified += 1
        self.deferred = 0
        if accepted:
            self.normal = None  # a new structure: its equations start from its first refresh
            self.champion_kind = "identified"
            self.every = p.min_every if code in _WON else self.every
        elif code in _KEPT:
            self.every = min(p.max_every, 2 * self.every)
        else:
            self.every = p.min_every
        self.due_in = self.every - 1

    def snapshot(self) -> dict[str, Any]:
        """What :meth:`restore` resumes (JSON-ready: the normal equations as lists of floats, exact)."""
        ne = self.normal
        return {"every": self.every, "due_in": self.due_in, "force": self.force, "refreshed": self.refreshed,
                "refreshes_accepted": self.refreshes_accepted, "identified": self.identified, "last": self.last,
                "champion": self.champion_kind, "deferred": self.deferred, "deferred_total": self.deferred_total,
                "deferred_backlog": self.deferred_backlog,
                "normal": None if ne is None else {"basis": ne.basis, "a": ne.a.tolist(), "b": ne.b.tolist(),
                                                   "weight": ne.weight, "through_t_ns": ne.through_t_ns,
                                                   "rows": ne.rows}}

    def restore(self, part: dict[str, Any]) -> str:
        """Resume from a :meth:`snapshot`; returns why it could not ("": it did). A part that does not check out
        leaves the track as new (the next update then reruns the coevolution)."""
        try:
            ints = {k: part[k] for k in ("every", "due_in", "refreshed", "refreshes_accepted", "identified")}
            ints.update({k: part.get(k, 0) for k in ("deferred", "deferred_total", "deferred_backlog")})  # (absent before)
            texts = {k: part[k] for k in ("force", "last", "champion")}
            if not all(isinstance(v, int) and not isinstance(v, bool) and v >= -1 for v in ints.values()) or \
                    not all(isinstance(v, str) for v in texts.values()):
                return "refresh state: counters must be integers and reasons strings"
            ne, normal = part.get("normal"), None
            if ne is not None:
                a, b = np.array(ne["a"], dtype=np.float64), np.array(ne["b"], dtype=np.float64)
                p = b.shape[0] if b.ndim == 1 else -1
                if not 0 < p <= MAX_REFRESH_COLUMNS or a.shape != (p, p) or not np.isfinite(a).all() or \
                        not np.isfinite(b).all() or not isinstance(ne["basis"], str):
                    return f"refresh state: normal equations must be finite, square and at most {MAX_REFRESH_COLUMNS} wide"
                normal = NormalEquations(ne["basis"], a, b, float(ne["weight"]), int(ne["through_t_ns"]), int(ne["rows"]))
        except (KeyError, TypeError, ValueError) as exc:
            return f"refresh state unusable ({type(exc).__name__}: {exc!s:.100})"
        self.every, self.due_in = min(int(ints["every"]), self.policy.max_every), int(ints["due_in"])
        self.refreshed, self.refreshes_accepted, self.identified, self.deferred, self.deferred_total = (
            int(ints[k]) for k in ("refreshed", "refreshes_accepted", "identified", "deferred", "deferred_total"))
        self.deferred_backlog = int(ints["deferred_backlog"])
        self.force, self.last, self.champion_kind = (str(texts[k])[:200] for k in ("force", "last", "champion"))
        self.normal = normal
        return ""

    def summary(self, next_reason: str) -> dict[str, Any]:
        """The status's ``refresh`` part of one output."""
        return {
            "next": "coevolution" if next_reason else "refresh",
            "next_reason": next_reason or None,
            "coevolution_every": self.every or self.policy.min_every,
            "refreshes_before_coevolution": max(0, self.due_in) if not next_reason else 0,
            "refreshed": self.refreshed,
            "refreshes_accepted": self.refreshes_accepted,
            "identified": self.identified,
            "deferred": self.deferred_total,  # scheduled runs that waited (refreshes instead) while the daemon was loaded
            "deferred_backlog": self.deferred_backlog,  # of them, while a live backlog was caught up
            "last": self.last or None,
            "champion": self.champion_kind or None,
            "rows": self.normal.rows if self.normal is not None else 0,
        }


def coevolve_reason(track: RefreshTrack, head: OutputHead, window: Window | None, cfg: StreamConfig) -> str:
    """Why ``head``'s next update must be a coevolution run ("": a refresh); ``window`` None: between windows."""
    return track.plan(
        champion=head.model, window=window, champion_signature=head.signature,
        signature=None if window is None else signature_of(window, cfg, head.output),
        escalate=head.escalate, failures_in_row=head.failures_in_row, current=head.current,
        min_r2_fr=cfg.min_r2_fr, min_r2_osa=cfg.min_r2_osa)


def refresh_job(track: RefreshTrack, head: OutputHead, window: Window, cfg: StreamConfig, version: int) -> RefreshJob:
    """The job refreshing ``head``'s champion on ``window`` (the version it would get: ``version``)."""
    return RefreshJob(window, cfg, version, head.coea_state, head.signature, output=head.output, champion=head.model,
                      champion_version=head.version, normal=track.normal, policy=track.policy)
