"""Models where engineers run them: an FMI 2.0 co-simulation FMU, or plain C99 code.

* :func:`write_fmu` -- ``streamid export MODEL.json --fmu OUT.fmu``: the FMU (model description, C sources,
  a binary compiled with the system's C compiler), runnable in any FMI 2.0 co-simulation tool, no Python;
* :func:`write_c` -- ``streamid export MODEL.json --c DIR``: ``<name>.h`` and ``<name>.c``, a fixed-size state,
  an init and a step function, no allocation, only ``exp`` of libm.

Both hold one model per output (several model files of one stream make one export) of every kind the engine
writes (single networks, ensembles, linear and long linear parts, direct terms), and follow one timing
convention (:data:`CONVENTION`, docs/export.md): a run equals :meth:`Model.simulate
<streamid.model.narx.Model.simulate>` from the same constant initial history. Each output comes with
``<output>_lower`` and ``<output>_upper`` (the model's 90 % band, when it carries an interval) and
``<output>_in_domain`` (1.0 while every regressor lies within its estimation range).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from streamid.model.narx import Model
from streamid.errors import ConfigError
from streamid.export.ccode import c_sources
from streamid.export.fmu import write_fmu
from streamid.export.plan import CONVENTION, ExportPlan, c_identifier, plan_of

__all__ = ["CONVENTION", "ExportPlan", "c_identifier", "plan_of", "write_c", "write_fmu"]


def write_c(models: Sequence[Model], directory: str | os.PathLike[str], *, name: str,
            period_s: float | None = None) -> tuple[Path, Path]:
    """Write ``<name>.h`` and ``<name>.c`` of ``models`` (one per output) into ``directory`` (created if needed).

    Everything is checked before a file is written; each file is written whole (renamed into place).
    Returns the header's and the source's paths.
    """
    plan = plan_of(models, name, period_s)
    code = c_sources(plan)
    folder = Path(directory)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"--c needs a folder; {str(folder)!r} is a file")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        paths = []
        for fname, text in ((code.header_name, code.header), (code.source_name, code.source)):
            target = folder / fname
            tmp = folder / f".{fname}.tmp"
            tmp.write_text(text, encoding="utf-8")
            os.replace(tmp, target)
            paths.append(target)
    except OSError as exc:
        raise ConfigError(f"cannot write the C code into {str(folder)!r}: {exc}") from None
    return paths[0], paths[1]
