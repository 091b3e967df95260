"""Issue 51: the prediction interval's calibration rules, compared on saved models without identifying again.

A measurement, not part of the engine. ``benchmarks.honesty`` saves every target and seed's models (documents);
this reads the ``hybrid`` one (the engine's kept model: :func:`benchmarks.honesty.hybrid`), and once per model
(cached under ``--cache``) records the free runs a calibration rule may read and those it is scored on:

* ``cal``: the model's structure refitted on the estimation record's first half, free-run over the whole record,
  on the second half: error, members' spread, distance past the domain (what the engine calibrates on today);
* ``rev``: the structure refitted on the second half, free-run from the record's start, on the first half (the
  same, the halves swapped: cross-fitting);
* ``own``: the model itself free-run over the estimation record (in sample);
* ``val``: the model on the validation experiment (centre, spread, far; periodic records: the second pass).

A *variant* (:data:`VARIANTS`) reads only the estimation record's runs (``cal``, ``rev``, ``own``) and gives the
band's half-width on the validation run; each is scored as ``benchmarks.suite.validation_band`` scores a band
(90 %): coverage, mean width over the free run's RMS error, and the silent failures
(``benchmarks.suite.silent_failures``)::

    python -m benchmarks.calibration_study /work/honesty_all.jsonl --build 0:40   # fill the cache, a slice at a time
    python -m benchmarks.calibration_study /work/honesty_all.jsonl               # the table, every variant x row
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.ablation import SYSTEMS, _targets, read_rows
from benchmarks.honesty import hybrid
from benchmarks.suite import Target, silent_failures
from streamid.engine.choice.calibration import UNSTABLE_HALF_R2
from streamid.engine.choice.robust import carries_long_linear
from streamid.engine.choice.selection import refit_weights
from streamid.engine.search.rows import spaced_rows
from streamid.engine.settings import RIDGE
from streamid.errors import DataError
from streamid.model.freerun import chunked_runs
from streamid.model.limits import CHUNK_ROWS
from streamid.model.narx import Model
from streamid.model.uncertainty import BEYOND, member_spread

Arrays = dict[str, NDArray[np.float64]]
LEVEL = 0.9
#: the rows issue 51's "calibrated and sharp" target is judged on: median validation FR R^2 at least this
SHARP_R2 = 0.95


def hybrid_doc(row: dict[str, Any]) -> dict[str, Any]:
    """The document of the row's hybrid model (:func:`benchmarks.honesty.hybrid`'s rule)."""
    models = row.get("models") or {}
    kept, med = models.get("kept"), models.get("median")
    if med is None or row.get("median") is None or carries_long_linear(Model.from_dict(kept)):
        return dict(kept)
    return dict(med)


def _run(model: Model, u: NDArray[np.float64], y: NDArray[np.float64], start: int, stop: int) -> Arrays:
    """The model's free run over ``u`` from ``y``'s first outputs; on samples ``start .. stop``: y, centre, spread, far."""
    n = int(u.shape[0])
    ua = u.reshape(n, -1)
    cen, spr, far = np.empty(n), np.empty(n), np.empty(n)
    for a, paths, centre, f in chunked_runs(model, ua, y[: model.max_lag], CHUNK_ROWS):
        b = a + paths.shape[1]
        cen[a:b], spr[a:b] = centre, member_spread(paths)
        far[a:b] = 0.0 if f is None else f
    return {"y": np.asarray(y[start:stop], dtype=np.float64), "centre": cen[start:stop], "spread": spr[start:stop],
            "far": far[start:stop]}


def _refit(model: Model, u: NDArray[np.float64], y: NDArray[np.float64]) -> Model | None:
    spaced = spaced_rows(int(y.shape[0]) - model.max_lag)
    try:
        return refit_weights(model, u, y, RIDGE, None if spaced is None else model.max_lag + spaced)
    except DataError:
        return None


def features(model: Model, t: Target) -> Arrays:
    """The runs a variant reads and is scored on (module docstring), flat: ``cal_y``, ``cal_centre``, ..."""
    u, y = t.u_est, t.y_est
    n = int(y.shape[0])
    h, L = n // 2, model.max_lag
    out: Arrays = {}
    with np.errstate(all="ignore"):
        first = _refit(model, u[:h], y[:h])
        if first is not None:
            out.update({f"cal_{k}": v for k, v in _run(first, u, y, h, n).items()})
        second = _refit(model, u[h:], y[h:])
        if second is not None:
            out.update({f"rev_{k}": v for k, v in _run(second, u[:h], y[:h], L, h).items()})
        out.update({f"own_{k}": v for k, v in _run(model, u, y, L, n).items()})
        if t.periodic_val:
            nv = int(t.y_val.shape[0])
            run = _run(model, np.concatenate([t.u_val, t.u_val]), np.concatenate([t.y_val, t.y_val]), nv, 2 * nv)
        else:
            run = _run(model, t.u_val, t.y_val, L, int(t.y_val.shape[0]))
        out.update({f"val_{k}": v for k, v in run.items()})
    out["h"] = np.array([h, L], dtype=np.float64)
    return out


def _target(name: str, found: dict[str, Target]) -> Target:
    if name not in found:
        system = next(s for s in SYSTEMS if any(t.name == name for t in _targets(s)))
        found.update({t.name: t for t in _targets(system)})
    return found[name]


def build(rows: list[dict[str, Any]], cache: str, lo: int, hi: int) -> None:
    """Fill the cache for rows ``lo .. hi`` (those not there yet)."""
    os.makedirs(cache, exist_ok=True)
    found: dict[str, Target] = {}
    for i in range(lo, min(hi, len(rows))):
        path = os.path.join(cache, f"{i:03d}.npz")
        if os.path.exists(path):
            continue
        r = rows[i]
        f = features(Model.from_dict(hybrid_doc(r)), _target(r["target"], found))
        np.savez(path, **f)
        print(f"{i} {r['target']} seed {r['seed']}", flush=True)


def conformal(scores: NDArray[np.float64], level: float = LEVEL) -> float:
    """The split-conformal quantile (:func:`streamid.model.uncertainty.conformal_quantiles`'s rule)."""
    s = np.sort(scores[np.isfinite(scores)])
    n = s.shape[0]
    return float(s[min(n, math.ceil((n + 1) * level)) - 1]) if n else math.inf


# ---- the variants: each reads the estimation runs and gives a half-width function of the validation run ----

Part = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]  # y, centre, spread, far


def _part(f: Arrays, p: str) -> Part | None:
    if f"{p}_y" not in f:
        return None
    y, c, s, d = f[f"{p}_y"], f[f"{p}_centre"], f[f"{p}_spread"], f[f"{p}_far"]
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(s))):
        return None
    return y, c, s, d


def _r2(p: Part) -> float:
    var = float(np.var(p[0]))
    return 1.0 - float(np.mean((p[0] - p[1]) ** 2)) / var if var > 0 else -math.inf


def _engine_part(f: Arrays) -> Part | None:
    """The calibration run the engine reads today: the first-half refit's, or the model's own second half when
    that refit leaves the record and the model does not."""
    cal = _part(f, "cal")
    h = int(f["h"][0]) - int(f["h"][1])
    own = _part(f, "own")
    if cal is None:
        return None
    if _r2(cal) < UNSTABLE_HALF_R2 and own is not None:
        mine = tuple(a[h:] for a in own)
        if _r2(mine) >= UNSTABLE_HALF_R2:  # type: ignore[arg-type]
            return mine  # type: ignore[return-value]
    return cal


Den = Callable[[float, NDArray[np.float64], NDArray[np.float64], float], NDArray[np.float64]]


def _den_engine(scale: float, spread: NDArray[np.float64], far: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    return scale + spread + BEYOND * far


def _den_k(k: float) -> Den:
    def den(scale: float, spread: NDArray[np.float64], far: NDArray[np.float64], _: float) -> NDArray[np.float64]:
        return scale + k * spread + BEYOND * far
    return den


def _scores(p: Part, den: Den, scale: float) -> NDArray[np.float64]:
    d = den(scale, p[2], p[3], 0.0)
    return np.divide(np.abs(p[0] - p[1]), d, out=np.zeros_like(d), where=d > 0)


def _rms(p: Part) -> float:
    return float(np.sqrt(np.mean((p[0] - p[1]) ** 2)))


def engine(f: Arrays) -> Callable[[Part], NDArray[np.float64]] | None:
    """Today's rule: scale and quantile from the engine's calibration run, denominator scale + spread + far."""
    return _fixed(f, _den_engine, parts=("engine",))


def _fixed(f: Arrays, den: Den, parts: tuple[str, ...]) -> Callable[[Part], NDArray[np.float64]] | None:
    """One denominator; scores pooled from ``parts`` (each with its own scale); the band's scale the first's."""
    got = [(_engine_part(f) if p == "engine" else _part(f, p)) for p in parts]
    got = [g for g in got if g is not None]
    if not got:
        return None
    scale = _rms(got[0])
    scores = np.concatenate([_scores(g, den, _rms(g)) for g in got])
    q = conformal(scores)
    return lambda v: q * den(scale, v[2], v[3], 0.0)


VARIANTS: dict[str, Callable[[Arrays], Callable[[Part], NDArray[np.float64]] | None]] = {
    "engine": engine,
}


def score(f: Arrays, half: NDArray[np.float64]) -> dict[str, float]:
    y, c = f["val_y"], f["val_centre"]
    with np.errstate(all="ignore"):
        inside = np.abs(y - c) <= half
        width = float(np.mean(2 * half))
        rms = float(np.sqrt(np.mean((y - c) ** 2)))
    return {"coverage": float(np.mean(inside)), "width_over_rms": width / rms if rms > 0 else math.inf,
            "width_over_std": width / float(np.std(y))}


def table(rows: list[dict[str, Any]], cache: str, names: list[str]) -> list[str]:
    by: dict[str, list[int]] = {}
    for i, r in enumerate(rows):
        by.setdefault(r["target"], []).append(i)
    feats = {i: dict(np.load(os.path.join(cache, f"{i:03d}.npz"))) for i in range(len(rows))}
    lines = ["| target (FR R2 median) | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    met, silent = dict.fromkeys(names, 0), dict.fromkeys(names, 0)
    for name, idx in by.items():
        frs = [float(hybrid(rows[i])["fr_val"]) for i in idx]
        paper_median = statistics.median(rows[i]["paper"]["fr_val"] for i in idx)
        sharp = statistics.median(frs) >= SHARP_R2
        cells = []
        for v in names:
            bands: list[dict[str, float] | None] = []
            for i in idx:
                make = VARIANTS[v](feats[i])
                v_part = _part(feats[i], "val")
                bands.append(None if make is None or v_part is None else score(feats[i], make(v_part)))
            ok = [b for b in bands if b is not None]
            cov = statistics.median(b["coverage"] for b in ok) if ok else math.nan
            wr = statistics.median(b["width_over_rms"] for b in ok) if ok else math.nan
            s = silent_failures(frs, bands, paper_median)  # type: ignore[arg-type]
            silent[v] += s
            good = sharp and 0.85 <= cov <= 0.97 and wr <= 4.0
            met[v] += good
            cells.append(f"{cov:.2f} / {wr:.2f} / {s}" + (" ✓" if good else (" ✗" if sharp else "")))
        lines.append(f"| {name} ({statistics.median(frs):.4f}) | " + " | ".join(cells) + " |")
    lines.append("| sharp rows met / silent | " + " | ".join(f"{met[v]} / {silent[v]}" for v in names) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.calibration_study", description=(__doc__ or "").split("\n")[0])
    ap.add_argument("rows", help="benchmarks.honesty's saved rows (JSONL, with the models)")
    ap.add_argument("--cache", default="/tmp/calibration_study", help="where the runs are kept (npz, one per row)")
    ap.add_argument("--build", metavar="LO:HI", help="fill the cache for rows LO..HI (then print nothing else)")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated, of: " + ", ".join(VARIANTS))
    a = ap.parse_args(argv)
    rows = read_rows(a.rows)
    if a.build:
        lo, hi = (int(x) for x in a.build.split(":"))
        build(rows, a.cache, lo, hi)
        return 0
    print("\n".join(table(rows, a.cache, a.variants.split(","))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
