"""One rule for names on every path a model takes (issue 52, item 1), and exports that are whole or refused.

* the model reader refuses a name breaking the rule (control characters, NUL, line feeds, tabs, lone
  surrogates, noncharacters, empty, not a string), duplicates, and names streamid adds for an output
  (``initial_<output>``, ``<output>_lower``, ``<output>_upper``, ``<output>_in_domain``): one line naming the
  field and the character; names that were valid and are legal FMI names stay valid;
* an export of hostile but legal names (markup, quotes, comment ends, trigraphs) is an FMU fmpy finds no problem
  in, whose documentation carries no markup from a name, and C code gcc compiles with -Werror;
* numbers C cannot spell (2 w^2 of a width of 1e200) are refused before any file; a range near the float64
  limit exports (its middle computed without overflow);
* ``streamid export`` on a name with a lone surrogate: one line, exit 2, no file; its success line is escaped;
* ``fmi2DoStep`` refuses infinite, NaN, negative and 2^53-period steps with fmi2Error.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from export_models import kinds, net
from streamid.model.narx import Model
from streamid.errors import ModelFormatError
from streamid.export import write_c, write_fmu
from streamid.export.plan import plan_of
from streamid.wire.names import unsafe_char

fmpy = pytest.importorskip("fmpy", reason="needs fmpy (pip install '.[test]')")
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.model_description import read_model_description  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

STREAMID = [sys.executable, "-m", "streamid"]


def need_cc() -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("needs a C compiler (Debian package gcc)")
    return cc


def doc(**fields: Any) -> dict[str, Any]:
    d = kinds()["network"].to_dict()  # inputs force_N, valve; output pos_mm
    d.update(fields)
    return d


BAD = [
    ({"inputs": ["f\x00", "valve"]}, "'inputs'[0]", "U+0000 at position 1"),
    ({"inputs": ["force_N", "a\nb"]}, "'inputs'[1]", "U+000A at position 1"),
    ({"inputs": ["\tv", "valve"]}, "'inputs'[0]", "U+0009 at position 0"),
    ({"inputs": ["force_N", "x\x1b[2J"]}, "'inputs'[1]", "U+001B"),
    ({"output": "v\ud800"}, "'output'", "U+D800 at position 1"),
    ({"output": "y\uffff"}, "'output'", "U+FFFF at position 1"),
    ({"output": "y\u202e"}, "'output'", "U+202E"),
    ({"output": ""}, "'output'", "1 to 256 UTF-8 bytes; got 0"),
    ({"output": "y" * 257}, "'output'", "got 257 bytes"),
    ({"inputs": [3, "valve"]}, "'inputs'[0]", "must be a string; got int"),
    ({"inputs": ["v", "v"]}, "'inputs'[1] 'v' is also 'inputs'[0]", "distinct"),
    ({"output": "valve"}, "'output' 'valve' is also 'inputs'[1]", "distinct"),
    ({"inputs": ["force_N", "initial_pos_mm"]}, "'inputs'[1] 'initial_pos_mm'", "reserved"),
    ({"inputs": ["pos_mm_lower", "valve"]}, "'inputs'[0] 'pos_mm_lower'", "reserved"),
    ({"inputs": ["force_N", "pos_mm_upper"]}, "'pos_mm_upper' is a name streamid adds", "reserved"),
    ({"inputs": ["force_N", "pos_mm_in_domain"]}, "'pos_mm_in_domain'", "reserved"),
]


@pytest.mark.parametrize(("fields", "where", "what"), BAD)
def test_the_model_reader_refuses_a_name_breaking_the_rule_in_one_line(
        fields: dict[str, Any], where: str, what: str, tmp_path: Path) -> None:
    with pytest.raises(ModelFormatError) as info:
        Model.from_dict(doc(**fields))
    msg = str(info.value)
    assert where in msg and what in msg, msg
    assert "\n" not in msg and unsafe_char(msg) is None  # safe to print as it is
    path = tmp_path / "m.json"  # the same from a file (json escapes the surrogate: valid JSON text)
    path.write_text(json.dumps(doc(**fields)), encoding="utf-8")
    with pytest.raises(ModelFormatError, match="model field"):
        Model.load(path)


def test_names_that_were_valid_and_are_legal_fmi_names_stay_valid() -> None:
    for name in ("force_N", "Weg_µm 温度", "R²", "<script>alert(1)</script>", 'a"&b', "x??/", "*/ evil /*", "C:\\u",
                 " padded ", "y\u0378", "initial", "lower_y", "y-1", "1"):
        assert name == "force_N" or Model.from_dict(doc(output=name)).output_name == name
        assert Model.from_dict(doc(inputs=[name, "valve"])).input_names == (name, "valve")
    assert Model.from_dict({k: v for k, v in doc().items() if k not in ("inputs", "output")}).input_names == ("u0", "u1")


def test_an_export_refuses_outputs_whose_names_clash_across_models() -> None:
    a = kinds()["network"]
    for other in ("initial_pos_mm", "pos_mm_lower", "pos_mm_upper", "pos_mm_in_domain", "force_N"):
        with pytest.raises(ModelFormatError, match=r"export 'outputs'\[1\]|export 'inputs'\[0\]"):
            plan_of([a, replace(a, output_name=other)], "x", 0.01)


HOSTILE_INPUTS = ("<script>alert(1)</script>", 'a"&b\'')
HOSTILE_OUTPUT = "*/ y??/ /* 温度 \\"


def test_hostile_but_legal_names_make_a_valid_fmu_and_c_that_compiles(tmp_path: Path) -> None:
    cc = need_cc()
    m = replace(net([("y", 0, 1), ("u", 0, 0), ("u", 1, 2)], linear="own", output=HOSTILE_OUTPUT),
                input_names=HOSTILE_INPUTS)
    m = Model.from_dict(json.loads(m.to_json()))  # through the reader: the names pass the rule
    fmu = write_fmu([m], tmp_path / "hostile.fmu")
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert [v.name for v in md.modelVariables] == [*HOSTILE_INPUTS, HOSTILE_OUTPUT, f"initial_{HOSTILE_OUTPUT}",
                                                   f"{HOSTILE_OUTPUT}_in_domain"]
    page = zipfile.ZipFile(fmu).read("documentation/index.html").decode()
    assert "<script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    h, c = write_c([m], tmp_path / "c", name="hostile")
    done = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-c", str(c), "-o", str(tmp_path / "h.o")],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert "??/" not in h.read_text() and "??/" not in c.read_text()  # no trigraph from a name


def test_numbers_c_cannot_spell_are_refused_before_any_file_and_near_limit_ranges_export(tmp_path: Path) -> None:
    cc = need_cc()
    wide = doc()
    wide["widths"][0] = 1e200  # a valid model (1 / (2 w^2) is 0): but 2 w^2 is inf in the generated code
    bad = tmp_path / "wide.json"
    bad.write_text(json.dumps(wide))
    out = tmp_path / "out"
    r = subprocess.run([*STREAMID, "export", str(bad), "--c", str(out), "--fmu", str(tmp_path / "w.fmu")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "two_w2" in r.stderr and "inf" in r.stderr and "C cannot spell" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and not (tmp_path / "w.fmu").exists()
    big = doc()
    big["normalisation"]["y_low"], big["normalisation"]["y_high"] = 1.0e308, 1.7e308  # lo + hi overflows
    m = Model.from_dict(big)
    assert math.isinf(m.normalisation.y_low + m.normalisation.y_high)
    _, c = write_c([m], tmp_path / "big", name="big")
    assert "inf" not in c.read_text()
    done = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-c", str(c), "-o", str(tmp_path / "b.o")],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr


def test_cli_export_of_a_lone_surrogate_name_is_one_line_and_its_success_line_is_escaped(tmp_path: Path) -> None:
    need_cc()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc(inputs=["v\ud800", "valve"])))  # ASCII JSON text: "v\ud800"
    r = subprocess.run([*STREAMID, "export", str(bad), "--fmu", str(tmp_path / "m.fmu")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "'inputs'[0] 'v\\ud800' holds U+D800 at position 1" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "m.fmu").exists()
    odd = tmp_path / "odd.json"
    odd.write_text(json.dumps(doc(output="y\u0378")))  # legal (unassigned), shown escaped
    r = subprocess.run([*STREAMID, "export", str(odd), "--fmu", str(tmp_path / "odd.fmu")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "outputs y\\u0378;" in r.stdout and "\u0378" not in r.stdout
    assert validate_fmu(str(tmp_path / "odd.fmu")) == []


def test_fmi2_do_step_refuses_infinite_nan_negative_and_huge_steps(tmp_path: Path) -> None:
    need_cc()
    path = write_fmu([kinds()["network"]], tmp_path / "step.fmu")
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    said: list[str] = []

    def logger(env: object, name: object, status: int, category: object, message: bytes) -> None:
        said.append(message.decode() if isinstance(message, bytes) else str(message))

    from fmpy import calloc, free
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    d = fmpy.extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate(loggingOn=True, callbacks=callbacks)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    try:
        h = 0.01
        for t, step in ((0.0, math.inf), (0.0, math.nan), (0.0, -h), (0.0, 0.0), (math.nan, h), (math.inf, h),
                        (0.0, 2.0**53 * h)):
            with pytest.raises(Exception, match=r"fmi2DoStep failed with status 3 \(error\)"):
                fmu.doStep(currentCommunicationPoint=t, communicationStepSize=step)
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=h)  # a good step still runs (fmi2OK)
    finally:
        fmu.terminate()
        fmu.freeInstance()
        shutil.rmtree(d, ignore_errors=True)
    assert sum("finite whole multiple" in s for s in said) >= 5, said
