"""streamid export --c: the C99 code compiles with gcc -std=c99 -Wall -Wextra -Werror, calls nothing but
``exp`` (and ``sqrt`` for an ensemble's band; no allocation), documents itself, and its step function equals
``Model.simulate`` from the same constant initial history to 1e-9 of the output's range at every sample, for
every model kind (a median ensemble: the per-sample median of its members), and so do its added outputs: the
90 % band ``Model.simulate(..., interval=0.9)`` gives and the estimation domain
:func:`streamid.model.domain.outside` finds (a small C driver, compiled and run, prints them)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from export_models import INPUTS, check_added_outputs, kinds, record, second_output
from streamid.model.narx import Model
from streamid.export import plan_of, write_c

KINDS = [*kinds(), "two_outputs"]
STREAMID = [sys.executable, "-m", "streamid"]
GCC = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]

DRIVER = r"""#include <stdio.h>
#include "@N@.h"
int main(void)
{
    @N@_state s;
    double u[@N_UP@_N_INPUTS], y[@N_UP@_N_OUTPUTS], initial[@N_UP@_N_OUTPUTS], x[@N_UP@_N_EXTRAS];
    int i;
    for (i = 0; i < @N_UP@_N_OUTPUTS; ++i)
        if (scanf("%lf", &initial[i]) != 1) return 1;
    @N@_init(&s, initial);
    for (;;) {
        for (i = 0; i < @N_UP@_N_INPUTS; ++i)
            if (scanf("%lf", &u[i]) != 1) return 0;
        @N@_outputs_all(&s, u, y, x);  /* the added outputs of the sample (band, domain) */
        @N@_step(&s, u, y);
        for (i = 0; i < @N_UP@_N_OUTPUTS; ++i) printf("%.17g ", y[i]);
        for (i = 0; i < @N_UP@_N_EXTRAS; ++i) printf("%.17g%c", x[i], i + 1 < @N_UP@_N_EXTRAS ? ' ' : '\n');
    }
}
"""


def gcc() -> str:
    found = shutil.which("gcc")
    if found is None:
        pytest.skip("needs gcc (Debian package gcc)")
    return found


def models_of(kind: str) -> list[Model]:
    return [kinds()["direct"], second_output()] if kind == "two_outputs" else [kinds()[kind]]


@pytest.mark.parametrize("kind", KINDS)
def test_the_c_step_function_equals_model_simulate(kind: str, tmp_path: Path) -> None:
    cc = gcc()
    models, u = models_of(kind), record()
    h, c = write_c(models, tmp_path, name=kind)
    (tmp_path / "driver.c").write_text(DRIVER.replace("@N_UP@", kind.upper()).replace("@N@", kind))
    obj = tmp_path / f"{kind}.o"
    subprocess.run([cc, *GCC, "-c", "-o", str(obj), str(c)], check=True, capture_output=True, text=True)
    # no allocation, no I/O: the model's object file calls exp and nothing else
    if shutil.which("nm") is None:
        pytest.skip("needs nm (Debian package binutils)")
    undefined = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True, check=True).stdout.split()
    spread = any(len(o.networks) > 1 and o.band is not None for o in plan_of(models, "x").outputs)
    assert [s for s in undefined if s != "U"] == (["exp", "sqrt"] if spread else ["exp"]), undefined
    exe = tmp_path / "drive"
    subprocess.run([cc, *GCC, "-O2", "-I", str(tmp_path), "-o", str(exe), str(tmp_path / "driver.c"), str(obj), "-lm"],
                   check=True, capture_output=True, text=True)
    init = [m.normalisation.y_low + 0.7 * (m.normalisation.y_high - m.normalisation.y_low) for m in models]
    feed = " ".join(repr(v) for v in init) + "\n" + "\n".join(" ".join(repr(float(v)) for v in row) for row in u)
    out = subprocess.run([str(exe)], input=feed, capture_output=True, text=True, check=True, timeout=30).stdout
    got = np.array([[float(v) for v in ln.split()] for ln in out.splitlines()])
    extras = [name for _, name in plan_of(models, "x").extras]
    assert got.shape == (len(u), len(models) + len(extras))
    x = dict(zip(extras, got[:, len(models):].T))
    for j, m in enumerate(models):
        want = m.simulate(u, np.full(m.max_lag, init[j]))
        span = m.normalisation.y_high - m.normalisation.y_low
        assert np.max(np.abs(got[:, j] - want)) <= 1e-9 * span, (kind, m.output_name)
        assert np.allclose(got[: m.max_lag, j], init[j])  # the initial history, as Model.simulate's y_init
        check_added_outputs(m, u, init[j], x)
        if getattr(m, "combine", "mean") == "median":  # the median, not the mean, of the members
            mean = np.mean([net.simulate(u, np.full(m.max_lag, init[j])) for net in m.members], axis=0)
            assert np.max(np.abs(got[:, j] - mean)) > 1e-2 * span


def test_the_header_documents_inputs_outputs_units_period_and_timing(tmp_path: Path) -> None:
    h, _ = write_c(models_of("two_outputs"), tmp_path, name="plant")
    text = h.read_text()
    for needed in (*INPUTS, "pos_mm", "temp_C", "Sample period: 0.01 s", "Units:", "Timing convention",
                   "inputs of samples 0..k", "direct term", "plant_step", "plant_init", "plant_state",
                   "direct terms in force_N", "direct terms in valve", "max lag 4"):
        assert needed in text, needed


def test_cli_writes_the_c_files(tmp_path: Path) -> None:
    m = kinds()["ensemble_long_linear"].save(tmp_path / "my-model.json")
    r = subprocess.run([*STREAMID, "export", str(m), "--c", str(tmp_path / "c")], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "c" / "my_model.h").is_file() and (tmp_path / "c" / "my_model.c").is_file()
    r = subprocess.run([*STREAMID, "export", str(m), "--c", str(tmp_path / "d"), "--name", "9bad"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--name must be a C identifier" in r.stderr and not (tmp_path / "d").exists()


def test_models_that_do_not_go_together_are_refused_in_one_line(tmp_path: Path) -> None:
    from dataclasses import replace

    a = kinds()["network"].save(tmp_path / "a.json")
    other_inputs = replace(second_output(), input_names=("volts", "valve")).save(tmp_path / "b.json")
    no_period = replace(kinds()["linear"], window={}).save(tmp_path / "c.json")
    same_output = kinds()["direct"].save(tmp_path / "d.json")
    for models, said in (([a, other_inputs], "must take the same inputs in the same order"),
                         ([no_period], "records no sample period (its window has no period_ns): give it with --period"),
                         ([a, same_output], "two models of output 'pos_mm': give one model file per output")):
        r = subprocess.run([*STREAMID, "export", *map(str, models), "--c", str(tmp_path / "out")],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and said in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not (tmp_path / "out").exists()
    r = subprocess.run([*STREAMID, "export", str(no_period), "--c", str(tmp_path / "out"), "--period", "0.002"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "Sample period: 0.002 s" in (tmp_path / "out" / "c.h").read_text()


def test_a_model_whose_interval_lacks_the_90_percent_level_is_refused_in_one_line() -> None:
    from dataclasses import replace

    from streamid.errors import ModelFormatError
    from streamid.model.uncertainty import Interval

    odd = replace(kinds()["network"], interval=Interval((0.5, 0.8), (0.7, 1.3), 0.05, 200))
    with pytest.raises(ModelFormatError, match=r"its interval has no level 0.9 \(levels 0.5, 0.8\); the export's "
                                               r"<output>_lower and <output>_upper are the 90 % band"):
        plan_of([odd], "x")
