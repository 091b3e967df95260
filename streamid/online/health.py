"""A stream's health, output by output: why each output is degraded (plain state, no clock, no I/O).

A stream of several outputs has one champion per output, each accepted or refused on its own, so each
output is healthy or degraded on its own: a model accepted for one output does not clear another's
failure (before, the stream had one flag, and whichever output was accepted last made it read healthy).
The stream is degraded while any output it still has is; its reason names them, those failing alike
together.  What makes an output degraded is decided elsewhere (:func:`streamid.online.acceptance.degraded_after`).
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["Health"]

#: longest reason kept, per output and for the stream
REASON_CHARS = 500


class Health:
    """Why each output is degraded (``""``: a fault of the stream, not of one output)."""

    def __init__(self) -> None:
        self._why: dict[str, str] = {}

    def set(self, output: str, why: str, outputs: Sequence[str] = ()) -> None:
        """``output`` is degraded for ``why``; an empty ``why`` makes it healthy. Outputs no longer among the
        stream's ``outputs`` are forgotten: at most one entry per output the stream has, and the stream's own,
        however often a publisher renames its signals."""
        if outputs:
            self._why = self.current(outputs)
        if why:
            self._why[output] = why[:REASON_CHARS]
        else:
            self._why.pop(output, None)

    def current(self, outputs: Sequence[str]) -> dict[str, str]:
        """The degraded outputs among ``outputs`` (the stream's now: after a schema change renamed its signals,
        the old outputs' faults are moot), with the stream's own; every one while ``outputs`` is empty."""
        return {k: v for k, v in self._why.items() if not outputs or not k or k in outputs}

    def text(self, outputs: Sequence[str], *, one_output: bool) -> str:
        """Why the stream is degraded (``""``: it is not). With ``one_output`` the reason alone; else each
        degraded output named, those failing for the same reason together."""
        faults = self.current(outputs)
        if len(faults) == 1 and one_output:
            return next(iter(faults.values()))
        by_reason: dict[str, list[str]] = {}
        for out, why in sorted(faults.items()):
            by_reason.setdefault(why, []).append(out)
        return "; ".join(f"{', '.join(o for o in outs if o)}: {why}" if any(outs) else why
                         for why, outs in by_reason.items())[:REASON_CHARS]
