"""An FMI 2.0 co-simulation FMU of a model (one or several outputs), runnable with no Python.

The FMU (a zip file) holds:

* ``modelDescription.xml``: a real input per model input, a real output per modelled output, a real
  parameter ``initial_<output>`` per output (its initial value: the model's initial history, default the
  middle of the output's range), after them the added outputs ``<output>_lower`` and ``<output>_upper`` (the
  model's 90 % free-run band, when it carries an interval) and ``<output>_in_domain`` (1.0 when every regressor
  lies within its estimation range), the default experiment's step = the sample period, and each output's
  direct dependencies on the inputs (its direct terms, inputs at lag 0);
* ``sources/``: the model's C99 code (:mod:`streamid.export.ccode`), the FMI functions
  (:mod:`streamid.export.fmi2code`) and the FMI 2.0 standard headers (BSD-2, Modelica Association);
* ``binaries/linux64/<name>.so``: those compiled at export with the system's C compiler (none with
  ``sources_only``);
* ``documentation/``: the timing convention and the FMI headers' licence.

The file is written whole or not at all (a temporary file renamed into place).
"""

from __future__ import annotations

import hashlib
import html
import os
import platform
import tempfile
import uuid
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from xml.sax.saxutils import quoteattr

from streamid._version import __version__
from streamid.model.narx import Model
from streamid.errors import ConfigError
from streamid.export.ccode import c_sources
from streamid.export.compiler import MAX_COMPILE_ESTIMATE_S, MAX_COMPILE_REGRESSORS, compile_budget_s, compile_shared
from streamid.export.fmi2code import fmi2_source
from streamid.export.plan import BAND_LEVEL, CONVENTION, ExportPlan, plan_of

__all__ = ["FMI_HEADERS", "FmuFiles", "compile_budget", "fmu_files", "model_description", "platform_dir", "write_fmu"]

FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")


def platform_dir() -> str:
    """The FMI 2.0 binaries folder of this machine (``linux64``, ``darwin64``, ``win64``, ...)."""
    system = {"Linux": "linux", "Darwin": "darwin", "Windows": "win"}.get(platform.system(), platform.system().lower())
    return f"{system}{'64' if platform.architecture()[0] == '64bit' else '32'}"


def _library_suffix() -> str:
    return {"Darwin": ".dylib", "Windows": ".dll"}.get(platform.system(), ".so")


def _guid(plan: ExportPlan, code: str) -> str:
    return "{" + str(uuid.UUID(hashlib.sha256(code.encode()).hexdigest()[:32])) + "}"


def model_description(plan: ExportPlan, guid: str, *, source_files: Sequence[str]) -> str:
    """The ``modelDescription.xml`` of ``plan``'s FMU."""
    ni, no = len(plan.inputs), len(plan.outputs)
    var: list[str] = []
    for i, name in enumerate(plan.inputs):
        start = 0.5 * plan.outputs[0].u_low[i] + 0.5 * plan.outputs[0].u_high[i]
        var.append(f'    <ScalarVariable name={quoteattr(name)} valueReference="{i}" causality="input" '
                   f'variability="continuous" description="model input {i}">\n      <Real start="{start!r}"/>\n'
                   "    </ScalarVariable>")
    for j, o in enumerate(plan.outputs):
        var.append(f'    <ScalarVariable name={quoteattr(o.name)} valueReference="{ni + j}" causality="output" '
                   f'variability="continuous" initial="calculated" description='
                   f'{quoteattr(f"model output (max lag {o.max_lag}; range seen {o.y_low!r} .. {o.y_high!r})")}>\n'
                   "      <Real/>\n    </ScalarVariable>")
    for j, o in enumerate(plan.outputs):
        var.append(f'    <ScalarVariable name={quoteattr("initial_" + o.name)} valueReference="{ni + no + j}" '
                   'causality="parameter" variability="fixed" initial="exact" description='
                   f'{quoteattr(f"the value of every past {o.name} before the start: the first {o.max_lag} samples")}>\n'
                   f'      <Real start="{o.middle!r}"/>\n    </ScalarVariable>')
    for x, (j, name) in enumerate(plan.extras):
        o = plan.outputs[j]
        what = (f"1.0 when every regressor of {o.name} at the sample lies within the range the model saw, else 0.0"
                if name.endswith("_in_domain") else
                f"{'lower' if name.endswith('_lower') else 'upper'} bound of the {100 * BAND_LEVEL:g} % free-run band "
                f"of {o.name}")
        var.append(f'    <ScalarVariable name={quoteattr(name)} valueReference="{ni + 2 * no + x}" causality="output" '
                   f'variability="continuous" initial="calculated" description={quoteattr(what)}>\n'
                   "      <Real/>\n    </ScalarVariable>")
    outs, inits = [], []
    owners = [*range(no), *(j for j, _ in plan.extras)]  # each output variable's model output, in index order
    for k, j in enumerate(owners):
        o = plan.outputs[j]
        index = ni + k + 1 if k < no else ni + no + k + 1  # ModelVariables indices (1-based): inputs first
        deps = " ".join(str(i + 1) for i in o.direct_inputs)
        kinds = " ".join("dependent" for _ in o.direct_inputs)
        outs.append(f'      <Unknown index="{index}" dependencies="{deps}"'
                    + (f' dependenciesKind="{kinds}"' if deps else "") + "/>")
        ideps = " ".join([*(str(i + 1) for i in o.direct_inputs), str(ni + no + j + 1)])
        inits.append(f'      <Unknown index="{index}" dependencies="{ideps}"/>')
    files = "\n".join(f'        <File name="{f}"/>' for f in source_files)
    now = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName={quoteattr(plan.name)} guid="{guid}"
  description={quoteattr(plan.description + ". " + CONVENTION)}
  generationTool="streamid {__version__}" generationDateAndTime="{now}" variableNamingConvention="flat"
  numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{plan.name}" canHandleVariableCommunicationStepSize="false"
    canInterpolateInputs="false" maxOutputDerivativeOrder="0" canRunAsynchronuously="false"
    canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="false"
    canGetAndSetFMUstate="false" canSerializeFMUstate="false" providesDirectionalDerivative="false">
    <SourceFiles>
{files}
    </SourceFiles>
  </CoSimulation>
  <DefaultExperiment startTime="0.0" stepSize="{plan.period_s!r}"/>
  <ModelVariables>
{chr(10).join(var)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{chr(10).join(outs)}
    </Outputs>
    <InitialUnknowns>
{chr(10).join(inits)}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


@dataclass(frozen=True)
class FmuFiles:
    """The text files of an FMU by their path inside it (the binary is compiled from ``sources/``)."""

    plan: ExportPlan
    guid: str
    files: tuple[tuple[str, str], ...]


def _fmi_header(name: str) -> str:
    return resources.files("streamid.export").joinpath("fmi2", name).read_text(encoding="utf-8")


def fmu_files(plan: ExportPlan) -> FmuFiles:
    """Every text file of ``plan``'s FMU (model description, sources, documentation)."""
    c = c_sources(plan)
    guid = _guid(plan, c.header + c.source)
    wrapper = f"fmi2_{plan.name}.c"
    srcs = [c.source_name, wrapper]
    files = [
        ("modelDescription.xml", model_description(plan, guid, source_files=srcs)),
        (f"sources/{c.header_name}", c.header),
        (f"sources/{c.source_name}", c.source),
        (f"sources/{wrapper}", fmi2_source(plan, guid)),
        *((f"sources/{h}", _fmi_header(h)) for h in FMI_HEADERS),
        ("documentation/index.html",  # names are text here, never markup
         f"<html><body><h1>{html.escape(plan.name)}</h1><p>{html.escape(plan.description)}</p>"
         f"<p>Sample period {plan.period_s!r} s.</p><p>{html.escape(CONVENTION)}</p>"
         f"<p>Generated by streamid {html.escape(__version__)}.</p></body></html>\n"),
        ("documentation/licenses/fmi2-headers.txt", _fmi_header("LICENSE.txt")),
    ]
    return FmuFiles(plan, guid, tuple(files))


def compile_budget(plan: ExportPlan) -> float:
    """The seconds the compile of ``plan``'s binary may take (:func:`~streamid.export.compiler.compile_budget_s`);
    a ConfigError saying ``--sources-only`` when the model is beyond what is compiled here
    (:data:`~streamid.export.compiler.MAX_COMPILE_REGRESSORS`, :data:`~streamid.export.compiler.MAX_COMPILE_ESTIMATE_S`)."""
    sizes = [len(n.regressors) + len(n.linear_regressors) for _, n in plan.networks]
    numbers = sum(len(n.weights) * (len(n.regressors) + 2) + len(n.linear or ()) for _, n in plan.networks)
    estimate, budget = compile_budget_s(sizes, numbers)
    where = "; write its sources with --sources-only and compile them where time and memory allow"
    if max(sizes) > MAX_COMPILE_REGRESSORS:
        raise ConfigError(f"the model is too large to compile here: network {sizes.index(max(sizes))} has {max(sizes)} "
                          f"regressors (its own and its linear part's); a binary is compiled for at most "
                          f"{MAX_COMPILE_REGRESSORS} a network (gcc's time and memory grow with their square){where}")
    if estimate > MAX_COMPILE_ESTIMATE_S:
        raise ConfigError(f"the model is too large to compile here: its {len(sizes)} networks would take gcc about "
                          f"{estimate:.0f} s; a binary is compiled for models of at most {MAX_COMPILE_ESTIMATE_S:.0f} s "
                          f"(estimated){where}")
    return budget


def write_fmu(models: Sequence[Model], path: str | os.PathLike[str], *, name: str | None = None,
              period_s: float | None = None, sources_only: bool = False,
              cancelled: Callable[[], bool] | None = None) -> Path:
    """Write the FMU of ``models`` (one per output) to ``path``; returns the path.

    ``name``: the model identifier (default: ``path``'s stem as a C identifier). Everything is checked and
    compiled before the file appears; it is written whole or not at all. The compile has a time budget from the
    model's size (:func:`compile_budget`; a model beyond it is refused before anything is written) and stops, its
    process group killed, when ``cancelled()`` turns true.

    Raises
    ------
    ConfigError
        Models that cannot go together (:func:`~streamid.export.plan.plan_of`), no C compiler (unless
        ``sources_only``), a compile failure, or a path that cannot be written.
    ModelFormatError
        A model the generated code cannot reproduce.
    """
    from streamid.export.plan import c_identifier

    target = Path(path)
    if target.suffix != ".fmu":
        raise ConfigError(f"the FMU's file name must end in .fmu; got {str(target)!r}")
    plan = plan_of(models, name or c_identifier(target.stem), period_s)
    budget = None if sources_only else compile_budget(plan)
    built = fmu_files(plan)
    if not target.parent.is_dir():
        raise ConfigError(f"cannot write the FMU {str(target)!r}: the folder {str(target.parent)!r} does not exist")
    with tempfile.TemporaryDirectory(prefix="streamid-fmu-") as work:
        root = Path(work)
        for rel, text in built.files:
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_text(text, encoding="utf-8")
        binary = None
        if not sources_only:
            binary = root / "binaries" / platform_dir() / f"{plan.name}{_library_suffix()}"
            binary.parent.mkdir(parents=True)
            compile_shared([root / "sources" / f"{plan.name}.c", root / "sources" / f"fmi2_{plan.name}.c"],
                           root / "sources", binary, timeout_s=budget or 30.0, cancelled=cancelled)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        try:
            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
                for rel, _ in built.files:
                    zf.write(root / rel, rel)
                if binary is not None:
                    zf.write(binary, binary.relative_to(root).as_posix())
            os.replace(tmp, target)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise ConfigError(f"cannot write the FMU {str(target)!r}: {exc}") from None
    return target
