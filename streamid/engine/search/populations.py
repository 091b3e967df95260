"""Exportable state of a coevolution (both populations, their fitness, the best pair).

A :class:`CoEAState` warm-starts a :class:`~streamid.engine.search.coevolution.Coevolution`
on new data. It is written as JSON (``"format": "streamid.coea_state/1"``) or as
``.npz`` (arrays plus a JSON header, loaded with ``allow_pickle=False``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.model.regressors import Normalisation
from streamid.errors import ModelFormatError

__all__ = ["CoEAState", "STATE_FORMAT"]

STATE_FORMAT = "streamid.coea_state/1"


@dataclass(frozen=True, eq=False)
class CoEAState:
    """Exportable state of a coevolution: both populations, their fitness and the best pair.

    Fitness values are in the output units of the data the run saw; a warm
    start re-evaluates everything on its own data.
    """

    harmonies: NDArray[np.bool_]  # (P, D_H)
    harmony_fitness: NDArray[np.float64]  # (P,)
    params: NDArray[np.float64]  # (P, D_X)
    param_fitness: NDArray[np.float64]  # (P,)
    best_mask: NDArray[np.bool_]  # (D_H,)
    best_params: NDArray[np.float64]  # (D_X,)
    best_fitness: float
    neurons: int
    max_lag_y: int
    max_lag_u: int
    n_inputs: int
    normalisation: Normalisation
    generation: int = 0
    meta: dict[str, Any] = field(default_factory=dict)
    min_lag_u: int = 1  # each input's first candidate lag (0: its direct term u(t) too)

    def __post_init__(self) -> None:
        P, D = np.shape(self.harmonies)
        dx = (D + 1) * self.neurons
        checks = [
            (np.shape(self.harmony_fitness) == (P,), "harmony_fitness", (P,)),
            (np.shape(self.params) == (P, dx), "params", (P, dx)),
            (np.shape(self.param_fitness) == (P,), "param_fitness", (P,)),
            (np.shape(self.best_mask) == (D,), "best_mask", (D,)),
            (np.shape(self.best_params) == (dx,), "best_params", (dx,)),
        ]
        for ok, name, shape in checks:
            if not ok:
                raise ModelFormatError(f"CoEAState.{name} must have shape {shape}; got {np.shape(getattr(self, name))}")
        if self.min_lag_u not in (0, 1):
            raise ModelFormatError(f"CoEAState.min_lag_u must be 0 or 1; got {self.min_lag_u!r}")
        if D != self.max_lag_y + self.n_inputs * (self.max_lag_u - self.min_lag_u + 1):
            raise ModelFormatError(
                f"CoEAState has {D} candidate lags but max_lag_y + n_inputs * (max_lag_u - min_lag_u + 1) = "
                f"{self.max_lag_y} + {self.n_inputs} * ({self.max_lag_u} - {self.min_lag_u} + 1)"
            )
        for name in ("harmony_fitness", "params", "param_fitness", "best_params"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ModelFormatError(f"CoEAState.{name} must contain only finite numbers")
        if not np.isfinite(self.best_fitness):
            raise ModelFormatError(f"CoEAState.best_fitness must be finite; got {self.best_fitness!r}")

    @property
    def population(self) -> int:
        return int(self.harmonies.shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": STATE_FORMAT,
            "neurons": self.neurons,
            "max_lag_y": self.max_lag_y,
            "max_lag_u": self.max_lag_u,
            "n_inputs": self.n_inputs,
            "generation": self.generation,
            "normalisation": self.normalisation.to_dict(),
            "harmonies": self.harmonies.astype(int).tolist(),
            "harmony_fitness": self.harmony_fitness.tolist(),
            "params": self.params.tolist(),
            "param_fitness": self.param_fitness.tolist(),
            "best_mask": self.best_mask.astype(int).tolist(),
            "best_params": self.best_params.tolist(),
            "best_fitness": self.best_fitness,
            "meta": self.meta,
            **({"min_lag_u": self.min_lag_u} if self.min_lag_u != 1 else {}),  # (documents before it: 1)
        }

    def to_json(self) -> str:
        """JSON text, ``"format": "streamid.coea_state/1"``."""
        return json.dumps(self.to_dict(), allow_nan=False)

    @classmethod
    def from_dict(cls, d: Any) -> CoEAState:
        if not isinstance(d, dict) or d.get("format") != STATE_FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise ModelFormatError(f"a coevolution state must be a JSON object with format {STATE_FORMAT!r}; got {got!r}")
        try:
            return cls(
                harmonies=np.array(d["harmonies"], dtype=np.int64).astype(bool),
                harmony_fitness=np.array(d["harmony_fitness"], dtype=np.float64),
                params=np.array(d["params"], dtype=np.float64),
                param_fitness=np.array(d["param_fitness"], dtype=np.float64),
                best_mask=np.array(d["best_mask"], dtype=np.int64).astype(bool),
                best_params=np.array(d["best_params"], dtype=np.float64),
                best_fitness=float(d["best_fitness"]),
                neurons=int(d["neurons"]),
                max_lag_y=int(d["max_lag_y"]),
                max_lag_u=int(d["max_lag_u"]),
                n_inputs=int(d["n_inputs"]),
                normalisation=Normalisation.from_dict(d["normalisation"]),
                generation=int(d.get("generation", 0)),
                meta=dict(d.get("meta", {})),
                min_lag_u=int(d.get("min_lag_u", 1)),
            )
        except ModelFormatError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise ModelFormatError(f"coevolution state has a missing or malformed field: {type(exc).__name__}: {exc}") from None

    @classmethod
    def from_json(cls, text: str | bytes) -> CoEAState:
        try:
            d = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError, TypeError) as exc:
            raise ModelFormatError(f"a coevolution state must be JSON text; parsing failed: {exc}") from None
        return cls.from_dict(d)

    def save_npz(self, path: str | Path) -> None:
        """Write as ``.npz`` (arrays + a JSON header; loads with ``allow_pickle=False``)."""
        header = {k: v for k, v in self.to_dict().items() if k not in _ARRAYS}
        np.savez(
            path,
            header=np.array(json.dumps(header)),
            **{k: getattr(self, k) for k in _ARRAYS},
        )

    @classmethod
    def load_npz(cls, path: str | Path) -> CoEAState:
        try:
            with np.load(path, allow_pickle=False) as z:
                d = json.loads(str(z["header"]))
                for k in _ARRAYS:
                    d[k] = z[k].tolist()
        except (OSError, ValueError, KeyError) as exc:
            raise ModelFormatError(f"{path}: not a streamid coevolution state .npz ({exc})") from None
        return cls.from_dict(d)


_ARRAYS = ("harmonies", "harmony_fitness", "params", "param_fitness", "best_mask", "best_params")
