"""Whether an update's candidate (the *challenger*) replaces the served model (the *champion*).

Both are evaluated on the same data: the held-out newest part of the window just
identified, which neither was fitted on (the champion was fitted on an older
window, whose estimation part ends before this window's held-out part begins).
The rule (:func:`decide`), in order:

1. The challenger must be *valid*: finite predictions and figures, one-step-ahead
   R^2 >= ``min_r2_osa`` and free-run R^2 >= ``min_r2_fr`` (:func:`judge`).
   Otherwise it is rejected (``validation``).
2. With no champion yet, a valid challenger is accepted (``first``); also when the
   champion cannot run on the current data (its signals changed: ``champion_inapplicable``).
3. It is accepted if its free-run R^2 beats the champion's by at least
   ``challenger_margin`` (``better``; a margin of -1 accepts every valid challenger,
   one model per window as in the paper, since R^2 differences are unbounded: ``every``), or if the champion itself is no longer valid on
   the current data (free-run or OSA R^2 below the floors, or not finite) and the
   challenger's free run is better at all (``champion_invalid``).
4. Otherwise it is rejected (``not_better``) and the champion stays, its current-data
   figures recorded.

Free-run R^2 decides because a controller or simulator consumes the model's free
run; the one-step-ahead figure only has to pass its floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypeGuard

import numpy as np

from streamid.model import Model
from streamid.engine.validation import diverged_at
from streamid.online.recalibrate import describe
from streamid.online.stream_config import StreamConfig
from streamid.online.update import Outcome
from streamid.online.window_types import Event, Window

__all__ = ["Decision", "Update", "decide", "degraded_after", "judge"]


@dataclass(frozen=True)
class Decision:
    """Why a challenger was accepted or rejected (see the module docstring)."""

    accepted: bool
    code: str
    reason: str
    margin: float
    champion: dict[str, Any] | None = None  # {"version", "r2_fr_val", "r2_osa_val"} of the champion on the same data

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite figures as null)."""
        champ = None
        if self.champion is not None:
            champ = {k: (v if not isinstance(v, float) or np.isfinite(v) else None) for k, v in self.champion.items()}
        return {"accepted": self.accepted, "code": self.code, "reason": self.reason, "margin": self.margin,
                "champion": champ}


@dataclass(frozen=True, eq=False)
class Update:
    """The result of one update: a new model version, or a refusal with its reason.

    Attributes
    ----------
    kind
        ``"accepted"``, ``"rejected"``, ``"failed"`` or ``"dropped"``.
    reason, code
        Why, in words and as a short key: the decision's (``first``, ``better``, ``not_better``,
        ``validation`` ...) for an identified window, else why it failed or was dropped.
    version
        The version served after this update: the new one when accepted, else the previous.
    window
        The window identified.
    outcome
        The run's details: the candidate model, its validation figures, the fitness history...
    document, payload
        The model update document (``streamid.model-update/1``) and its JSON bytes: the accepted model, or
        the rejected challenger (``"accepted": false``; None if it had no finite figures).
    event
        The ``update.<kind>`` event.
    output
        The output the model predicts.
    decision
        Why it was accepted or rejected (None for failed/dropped updates).
    saved
        Whether the identifier's state was saved after it (False: ``persist`` failed; the model is
        published anyway, see :meth:`~streamid.online.OnlineIdentifier.finish`).
    """

    kind: str
    reason: str
    code: str
    version: int
    window: Window
    outcome: Outcome
    document: dict[str, Any] | None
    payload: bytes | None
    event: Event
    output: str = ""
    decision: Decision | None = None
    saved: bool = True

    @property
    def accepted(self) -> bool:
        """Whether this update changed the current model."""
        return self.kind == "accepted"

    @property
    def model(self) -> Model | None:
        """The model of this update (the candidate, also when it was rejected)."""
        return self.outcome.model

    @property
    def metrics(self) -> dict[str, float]:
        """The candidate's validation figures on the window (empty if it was never validated)."""
        return dict(self.outcome.summary.metrics) if self.outcome.summary is not None else {}


def judge(outcome: Outcome, cfg: StreamConfig) -> list[str]:
    """Why a candidate is not accepted (empty: it is)."""
    s = outcome.summary
    if s is None or outcome.model is None:
        return ["no model was produced"]
    m = s.metrics
    reasons = []
    if not s.finite:
        at = diverged_at(s.fr_val)
        reasons.append("non-finite predictions or metrics" if at is None else
                       f"its free run on the held-out data diverged (not finite from sample {at}): never published")
    if not m.get("r2_osa_val", -np.inf) >= cfg.min_r2_osa:
        reasons.append(f"validation R² OSA {m.get('r2_osa_val', float('nan')):.4g} < min_r2_osa {cfg.min_r2_osa:g}")
    if not m.get("r2_fr_val", -np.inf) >= cfg.min_r2_fr:
        reasons.append(f"validation R² FR {m.get('r2_fr_val', float('nan')):.4g} < min_r2_fr {cfg.min_r2_fr:g}")
    return reasons


def _fig(m: dict[str, Any] | None, key: str) -> float:
    v = None if m is None else m.get(key)
    return float(v) if isinstance(v, (int, float)) and np.isfinite(v) else -np.inf


def decide(outcome: Outcome, cfg: StreamConfig, champion_version: int) -> Decision:
    """Champion or challenger (see the module docstring); ``champion_version`` 0 means there is no champion."""
    margin = float(cfg.challenger_margin)
    reasons = judge(outcome, cfg)
    champ = outcome.champion_metrics
    champ_doc = None if champion_version == 0 or champ is None else {
        "version": champion_version, "r2_fr_val": _fig(champ, "r2_fr_val"), "r2_osa_val": _fig(champ, "r2_osa_val")}
    if reasons:
        return Decision(False, "validation", "; ".join(reasons), margin, champ_doc)
    m = outcome.summary.metrics if outcome.summary is not None else {}
    fr, osa = _fig(m, "r2_fr_val"), _fig(m, "r2_osa_val")
    if champion_version == 0:
        return Decision(True, "first", f"first model (FR R² {fr:.4f}, OSA R² {osa:.4f} on held-out data)", margin)
    if champ is None:
        return Decision(True, "champion_inapplicable",
                        f"champion v{champion_version} cannot run on the current signals", margin, champ_doc)
    c_fr, c_osa = _fig(champ, "r2_fr_val"), _fig(champ, "r2_osa_val")
    if margin <= -1.0:
        return Decision(True, "every", f"every valid challenger replaces the champion (challenger_margin -1): FR R² "
                        f"{fr:.4f} against champion v{champion_version}'s {c_fr:.4f} on the same held-out data"
                        f"{describe(outcome.model)}", margin, champ_doc)
    if fr >= c_fr + margin:
        word = "beats" if fr > c_fr else "is within the margin of"
        return Decision(True, "better", f"FR R² {fr:.4f} {word} champion v{champion_version}'s {c_fr:.4f} on the same "
                        f"held-out data ({fr - c_fr:+.4f}, margin {margin:g}){describe(outcome.model)}", margin,
                        champ_doc)
    champion_valid = c_fr >= cfg.min_r2_fr and c_osa >= cfg.min_r2_osa
    if not champion_valid and fr > c_fr:
        return Decision(True, "champion_invalid", f"champion v{champion_version} no longer valid on current data "
                        f"(FR R² {c_fr:.4f}, OSA R² {c_osa:.4f} vs floors {cfg.min_r2_fr:g}/{cfg.min_r2_osa:g}); "
                        f"challenger FR R² {fr:.4f}{describe(outcome.model)}", margin, champ_doc)
    return Decision(False, "not_better", f"FR R² {fr:.4f} not better than champion v{champion_version}'s {c_fr:.4f} "
                    f"on the same held-out data by margin {margin:g}", margin, champ_doc)


def degraded_after(decision: Decision, cfg: StreamConfig) -> str | None:
    """The stream's degraded reason after a rejected challenger whose champion ran on the same data
    (``""``: healthy), or None when the decision says nothing of the champion (no champion, another code).

    A stream is degraded when the model it serves is not valid on current data, not when one challenger fails
    the floors while a valid champion serves: that is counted (``decisions.validation``) and evented. (Before,
    every challenger refused for ``validation`` marked the stream degraded until the next acceptance: one
    poor window made healthy streams read DEGRADED.)
    """
    champ = decision.champion
    if decision.accepted or champ is None or decision.code not in ("validation", "not_better"):
        return None
    fr, osa = champ.get("r2_fr_val"), champ.get("r2_osa_val")
    if _finite(fr) and _finite(osa) and fr >= cfg.min_r2_fr and osa >= cfg.min_r2_osa:
        return ""
    lead = f"{decision.reason}; " if decision.code == "validation" else ""
    return (f"{lead}champion v{champ.get('version')} is not valid on the same data either (R² FR {_text(fr)}, "
            f"OSA {_text(osa)}; floors min_r2_fr {cfg.min_r2_fr}, min_r2_osa {cfg.min_r2_osa})")[:500]


def _finite(v: Any) -> TypeGuard[float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _text(v: Any) -> str:
    return f"{v:.4f}" if _finite(v) else "not finite"
