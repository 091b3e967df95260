"""Hashes of a few identifications' model documents: a change meant to leave the engine's models as they were
(a setting retired into a constant, a refactor) is checked by running this before and after it.

    python -m benchmarks.model_hashes

Five identifications on `benchmarks.suite` targets (the defaults on piezo_sim's noise record seed 1, the F-16
accel1 seed 0, the bundled MR damper seed 0 and the reactor's steps seed 2; `--paper` on the MR damper seed 3).
Each line: the target, the settings, the first 16 hex digits of the SHA-256 of the model document without its
configuration and metrics (which name the settings' fields), plus its estimation free-run R^2.
"""

from __future__ import annotations

import hashlib
import json

from benchmarks.suite import targets
from streamid.engine import identify
from streamid.engine.settings import DEFAULT, PAPER

#: (target name, settings name, seed)
CASES = (("piezo_sim [noise->sweep]", "defaults", 1), ("f16_gvt:accel1_au", "defaults", 0),
         ("mr_damper", "defaults", 0), ("mr_damper", "paper", 3), ("reactor_sim [uniform->steps]", "defaults", 2))


def model_hash(model_json: str, r2_fr_est: object) -> str:
    """First 16 hex digits of the SHA-256 of a model document without ``config`` and ``metrics``."""
    doc = {k: v for k, v in json.loads(model_json).items() if k not in ("config", "metrics")}
    doc["r2_fr_est"] = r2_fr_est
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()[:16]


def main() -> None:
    wanted = {name for name, _, _ in CASES}
    found = {t.name: t for t in targets(("piezo_sim", "f16", "mr_damper", "reactor_sim")) if t.name in wanted}
    for name, settings, seed in CASES:
        t = found[name]
        res = identify(t.u_est, t.y_est, DEFAULT if settings == "defaults" else PAPER, seed)
        print(f"{name} {settings} seed {seed}: {model_hash(res.model.to_json(), res.model.metrics.get('r2_fr_est'))}",
              flush=True)


if __name__ == "__main__":
    main()
