"""The served models of an :class:`~streamid.online.OnlineIdentifier`: its champions, their documents, predictions.

A mixin of the identifier (the part a consumer of the current model reads), kept apart so that the identifier's
module holds the update logic only.  It reads the identifier's ``_heads``, ``_buffer`` and ``config``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from streamid.model import Model
from streamid.model.predictor import one_step
from streamid.errors import DataError
from streamid.online.head import OutputHead

if TYPE_CHECKING:
    from streamid.online.stream_config import StreamConfig
    from streamid.online.window import WindowBuffer

__all__ = ["ChampionViews"]


class ChampionViews:
    """The current models (see the module docstring)."""

    config: StreamConfig
    _heads: dict[str, OutputHead]
    _buffer: WindowBuffer
    _version: int

    @property
    def version(self) -> int:
        """The stream's newest version (of any output; 0: none yet)."""
        return self._version

    @property
    def outputs(self) -> tuple[str, ...]:
        """The outputs modelled so far, in the stream's order."""
        return tuple(self._heads)

    @property
    def model(self) -> Model | None:
        """The champion of the first modelled output (``config.output``, or the stream's first), or None."""
        head = self._primary()
        return head.model if head is not None else None

    @property
    def models(self) -> dict[str, Model]:
        """The champion of every modelled output that has one."""
        return {k: h.model for k, h in self._heads.items() if h.model is not None}

    @property
    def document(self) -> dict[str, Any] | None:
        """The champion's update document (``streamid.model-update/1``) of the first modelled output, or None."""
        head = self._primary()
        return head.document if head is not None else None

    @property
    def payload(self) -> bytes | None:
        """:attr:`document` as compact JSON bytes (what the daemon publishes), or None."""
        head = self._primary()
        return head.payload if head is not None else None

    @property
    def payloads(self) -> tuple[bytes, ...]:
        """Every output's champion document as JSON bytes (what a query on the model key is answered with)."""
        return tuple(h.payload for h in self._heads.values() if h.payload is not None)

    def predict_one(self, output: str | None = None, u_next: ArrayLike | None = None) -> float | None:
        """One-step-ahead prediction of the next sample of ``output`` (default: the first modelled) from the newest samples.

        None if that output has no champion yet or fewer than ``max_lag`` complete samples are held
        since the last gap or reset.  ``u_next``, the input at the predicted instant, is needed only by
        a champion with direct terms (an input at lag 0, from ``direct_terms``): without it such a
        champion raises :class:`~streamid.errors.DataError`.  (A controller holding a received model
        uses :class:`~streamid.model.predictor.Predictor`, which computes the same.)
        """
        head = self._primary() if output is None else self._heads.get(output)
        m = head.model if head is not None else None
        if head is None or m is None:
            return None
        recent = self._buffer.recent(m.max_lag)
        names = self._buffer.output_names
        if recent is None or head.output not in names or recent[0].shape[1] != m.n_inputs:
            return None
        u, y = recent
        return one_step(m, u, y[:, names.index(head.output)], u_next)

    def simulate(self, u: ArrayLike, y_init: ArrayLike, output: str | None = None) -> NDArray[np.float64]:
        """Free run of an output's champion on inputs ``u`` from ``max_lag`` measured outputs ``y_init``.

        Raises
        ------
        DataError
            If that output has no model yet, or the data do not fit it.
        """
        head = self._primary() if output is None else self._heads.get(output)
        if head is None or head.model is None:
            raise DataError(f"no model yet for output {output or 'of the stream'}: simulate() needs an accepted update")
        return head.model.simulate(u, y_init)

    def _primary(self) -> OutputHead | None:
        if self.config.output is not None:
            return self._heads.get(self.config.output)
        return next(iter(self._heads.values()), None)
