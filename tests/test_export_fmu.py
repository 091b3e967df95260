"""streamid export --fmu, checked for real with fmpy (a well-kept FMI library, used only by the tests).

* fmpy's validation finds no problem in the FMU; its model description names the inputs, outputs and
  ``initial_<output>`` parameters, the sample period and the direct dependencies truthfully;
* fmpy runs the compiled FMU: with a master that sets a communication point's inputs before reading its
  outputs (fmpy's FMU2Slave, as FMI 2.0 masters do for direct feedthrough) it equals ``Model.simulate`` from
  the same constant initial history to 1e-6 of the output's range at every sample, for every model kind;
  fmpy's own loop (``simulate_fmu``) too for every kind without direct terms; its added outputs
  ``<output>_lower``/``_upper`` (the 90 % band, when the model carries an interval) and ``<output>_in_domain``
  equal ``Model.simulate(..., interval=0.9)`` and :func:`streamid.model.domain.outside` on the same inputs; with direct terms that loop
  reads the outputs before it sets the next inputs, and gets exactly the documented value for that order;
* a communication step of n sample periods advances n samples; any other step is refused (fmi2Error, logged);
* the binary does not link libpython; a model file failing the model checks is refused before any file.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from export_models import INPUTS, PERIOD_NS, check_added_outputs, kinds, record, second_output
from streamid.model.narx import Model
from streamid.export import write_fmu
from streamid.export.plan import plan_of

fmpy = pytest.importorskip("fmpy", reason="needs fmpy (pip install '.[test]')")
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.model_description import read_model_description  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

H = PERIOD_NS / 1e9
KINDS = [*kinds(), "two_outputs"]
STREAMID = [sys.executable, "-m", "streamid"]


def need_cc() -> None:
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")


def models_of(kind: str) -> list[Model]:
    return [kinds()["direct"], second_output()] if kind == "two_outputs" else [kinds()[kind]]


def signals(u: np.ndarray) -> np.ndarray:
    sig = np.zeros(len(u), dtype=[("time", float), *((name, float) for name in INPUTS)])
    sig["time"] = np.arange(len(u)) * H
    for i, name in enumerate(INPUTS):
        sig[name] = u[:, i]
    return sig


def initials(models: list[Model]) -> list[float]:
    """Initial values away from the default (the middle): the parameter must be used."""
    return [m.normalisation.y_low + 0.3 * (m.normalisation.y_high - m.normalisation.y_low) for m in models]


def reference(m: Model, u: np.ndarray, initial: float) -> np.ndarray:
    return m.simulate(u, np.full(m.max_lag, initial))


def err(m: Model, got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want)) / (m.normalisation.y_high - m.normalisation.y_low))


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    need_cc()
    root = tmp_path_factory.mktemp("fmus")
    return {k: write_fmu(models_of(k), root / f"{k}.fmu") for k in KINDS}


def test_fmpy_validation_finds_no_problem_and_the_description_is_truthful(fmus: dict[str, Path]) -> None:
    for kind, path in fmus.items():
        assert validate_fmu(str(path)) == [], kind
    md = read_model_description(str(fmus["two_outputs"]))
    assert md.fmiVersion == "2.0" and md.coSimulation is not None and md.modelExchange is None
    assert md.coSimulation.modelIdentifier == "two_outputs"
    by = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables if v.causality == "input"] == list(INPUTS)
    assert [v.name for v in md.modelVariables if v.causality == "output"] == ["pos_mm", "temp_C", "pos_mm_in_domain",
                                                                              "temp_C_in_domain"]
    for m in models_of("two_outputs"):
        p = by[f"initial_{m.output_name}"]
        assert (p.causality, p.variability, p.type) == ("parameter", "fixed", "Real")
        assert float(p.start) == pytest.approx(0.5 * (m.normalisation.y_low + m.normalisation.y_high))
    assert md.defaultExperiment is not None and float(md.defaultExperiment.stepSize) == H
    # direct terms: pos_mm has force_N(t), temp_C has valve(t), and nothing else directly
    deps = {u.variable.name: [d.name for d in u.dependencies] for u in md.outputs}
    assert deps == {"pos_mm": ["force_N"], "temp_C": ["valve"], "pos_mm_in_domain": ["force_N"],
                    "temp_C_in_domain": ["valve"]}
    one = read_model_description(str(fmus["network"]))
    assert {u.variable.name: [d.name for d in u.dependencies] for u in one.outputs} == {"pos_mm": [],
                                                                                        "pos_mm_in_domain": []}
    # a model with an interval: its band's bounds, after the parameters (the first value references unchanged)
    med = read_model_description(str(fmus["median"]))
    vrs = {v.name: (v.valueReference, v.causality, v.initial) for v in med.modelVariables}
    assert vrs == {"force_N": (0, "input", "exact"), "valve": (1, "input", "exact"), "pos_mm": (2, "output", "calculated"),
                   "initial_pos_mm": (3, "parameter", "exact"), "pos_mm_lower": (4, "output", "calculated"),
                   "pos_mm_upper": (5, "output", "calculated"), "pos_mm_in_domain": (6, "output", "calculated")}
    assert {u.variable.name: [d.name for d in u.dependencies] for u in med.outputs} == {
        n: ["force_N"] for n in ("pos_mm", "pos_mm_lower", "pos_mm_upper", "pos_mm_in_domain")}
    assert "90 % free-run band" in next(v.description for v in med.modelVariables if v.name == "pos_mm_upper")
    names = zipfile.ZipFile(fmus["network"]).namelist()
    assert "binaries/linux64/network.so" in names and "sources/network.c" in names
    assert "documentation/licenses/fmi2-headers.txt" in names and "sources/fmi2Functions.h" in names


def run_master(path: Path, models: list[Model], u: np.ndarray, init: list[float], every: int = 1,
               extras: list[str] | None = None) -> np.ndarray:
    """A co-simulation master with fmpy's FMU2Slave: at each communication point set the inputs, read the
    outputs (and the variables ``extras``, as columns after them), then step (``every`` sample periods a step)."""
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = fmpy.extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="master")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr[f"initial_{m.output_name}"] for m in models], init)
    fmu.exitInitializationMode()
    out, t = [], 0.0
    for k in range(0, len(u), every):
        fmu.setReal([vr[n] for n in INPUTS], list(u[k]))
        out.append(fmu.getReal([vr[m.output_name] for m in models] + [vr[n] for n in extras or ()]))
        fmu.doStep(currentCommunicationPoint=t, communicationStepSize=every * H)
        t = (k + every) * H
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(d, ignore_errors=True)
    return np.array(out)


@pytest.mark.parametrize("kind", KINDS)
def test_fmu_in_fmpy_equals_model_simulate(fmus: dict[str, Path], kind: str) -> None:
    models, u = models_of(kind), record()
    init = initials(models)
    extras = [name for _, name in plan_of(models, "x").extras]
    got = run_master(fmus[kind], models, u, init, extras=extras)
    for j, m in enumerate(models):
        want = reference(m, u, init[j])
        assert err(m, got[:, j], want) <= 1e-9, (kind, m.output_name)
        assert np.std(want[m.max_lag:]) > 0.05 * (m.normalisation.y_high - m.normalisation.y_low)  # not a flat run
        check_added_outputs(m, u, init[j], dict(zip(extras, got[:, len(models):].T)))
    # fmpy's own co-simulation loop: set the inputs of t_k, step, read the outputs at t_k+1
    res = fmpy.simulate_fmu(str(fmus[kind]), start_time=0.0, stop_time=(len(u) - 1) * H, output_interval=H,
                            input=signals(u), fmi_type="CoSimulation",
                            start_values={f"initial_{m.output_name}": v for m, v in zip(models, init)})
    for j, m in enumerate(models):
        rec = res[m.output_name]
        assert len(rec) == len(u)
        want = reference(m, u, init[j])
        direct = plan_of([m], "x", H).outputs[0].direct_inputs
        if not direct:
            assert err(m, rec, want) <= 1e-6, (kind, m.output_name)
            check_added_outputs(m, u, init[j], {n: res[n] for n in extras})  # fmpy records them too
        else:
            # it reads sample k's outputs before setting sample k's inputs: the direct terms still see u(t_k-1)
            # (docs/export.md); the master above, which sets them first, gets want exactly
            held = u.copy()
            held[1:] = u[:-1]
            stale = run_master_stale(fmus[kind], models, u, init)
            assert err(m, rec, stale[:, j]) <= 1e-6
            same = np.all(held == u, axis=1)
            assert err(m, rec[same], want[same]) <= 1e-6 if same.any() else True
            assert err(m, rec, want) > 1e-3  # and the difference is real: the set-then-read order matters


def run_master_stale(path: Path, models: list[Model], u: np.ndarray, init: list[float]) -> np.ndarray:
    """fmpy's loop order spelled out: read the outputs at t_k (inputs of t_k-1 still set), set t_k's, step."""
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = fmpy.extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr[f"initial_{m.output_name}"] for m in models], init)
    fmu.setReal([vr[n] for n in INPUTS], list(u[0]))
    fmu.exitInitializationMode()
    out = []
    for k in range(len(u)):
        out.append(fmu.getReal([vr[m.output_name] for m in models]))
        fmu.setReal([vr[n] for n in INPUTS], list(u[k]))
        fmu.doStep(currentCommunicationPoint=k * H, communicationStepSize=H)
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(d, ignore_errors=True)
    return np.array(out)


def test_a_step_of_several_periods_holds_the_inputs_and_other_steps_are_refused(fmus: dict[str, Path]) -> None:
    models, u = models_of("ensemble"), record(300)
    init = initials(models)
    got = run_master(fmus["ensemble"], models, u, init, every=3)
    held = np.repeat(u[::3], 3, axis=0)[: len(u)]  # the inputs held over each step's three samples
    want = reference(models[0], held, init[0])[::3]
    assert err(models[0], got[:, 0], want) <= 1e-6
    said: list[str] = []

    def logger(env: object, name: object, status: int, category: object, message: bytes) -> None:
        said.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception, match=r"fmi2DoStep failed with status 3 \(error\)"):
        fmpy.simulate_fmu(str(fmus["ensemble"]), start_time=0.0, stop_time=20 * H, output_interval=1.5 * H,
                          input=signals(u), fmi_type="CoSimulation", logger=logger)
    assert any("whole multiple" in s and "sample period 0.01" in s for s in said), said


def test_the_binary_does_not_link_libpython(fmus: dict[str, Path], tmp_path: Path) -> None:
    readelf = shutil.which("readelf")
    if readelf is None:
        pytest.skip("needs readelf (Debian package binutils)")
    with zipfile.ZipFile(fmus["ensemble_long_linear"]) as zf:
        so = tmp_path / "m.so"
        so.write_bytes(zf.read("binaries/linux64/ensemble_long_linear.so"))
    dyn = subprocess.run([readelf, "-d", str(so)], capture_output=True, text=True, check=True).stdout
    needed = [ln.split("[")[1].split("]")[0] for ln in dyn.splitlines() if "(NEEDED)" in ln]
    assert needed and not any("python" in n for n in needed), needed
    assert set(needed) <= {"libm.so.6", "libc.so.6"}, needed
    assert b"libpython" not in so.read_bytes()


def test_cli_refuses_a_bad_model_before_writing_any_file(tmp_path: Path) -> None:
    good = kinds()["network"].save(tmp_path / "good.json")
    doc = json.loads(good.read_text())
    doc["widths"][0] = -1.0  # fails the model checks (widths > 0)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    out = tmp_path / "out"
    r = subprocess.run([*STREAMID, "export", str(good), str(bad), "--fmu", str(out / "m.fmu"), "--c", str(out)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "widths must be > 0" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not out.exists()
    r = subprocess.run([*STREAMID, "export", str(good), "--fmu", str(tmp_path / "m.fmu")],
                       capture_output=True, text=True, timeout=60, env={"PATH": str(Path(sys.executable).parent)})
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "no C compiler found" in r.stderr and "apt-get install gcc" in r.stderr and "--sources-only" in r.stderr
    assert not (tmp_path / "m.fmu").exists()
    r = subprocess.run([*STREAMID, "export", str(good), "--fmu", str(tmp_path / "m.fmu"), "--sources-only"],
                       capture_output=True, text=True, timeout=60, env={"PATH": str(Path(sys.executable).parent)})
    assert r.returncode == 0, r.stderr
    names = zipfile.ZipFile(tmp_path / "m.fmu").namelist()
    assert "sources/m.c" in names and not any(n.startswith("binaries/") for n in names)
    assert validate_fmu(str(tmp_path / "m.fmu")) == []
