"""The README's export journey, each block run as printed: identify, export an FMU, run it with fmpy (a
well-kept FMI library, used only by the tests) and find it equal to ``Model.simulate``."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
HEADING = "### Run the model in a simulation tool (FMU)"
STREAMID = [sys.executable, "-m", "streamid"]


def block(lang: str) -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index(HEADING)
    end = text.index("\n## ", start)
    found = re.findall(rf"```{lang}\n(.*?)```", text[start:end], re.S)
    assert len(found) == 1, f"expected one {lang} block under {HEADING!r}"
    return str(found[0])


def test_readme_identify_export_and_simulate_the_fmu(tmp_path: Path) -> None:
    pytest.importorskip("fmpy", reason="needs fmpy (pip install '.[test]')")
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    lines = [ln for ln in block("sh").splitlines() if ln.strip()]
    assert [shlex.split(ln)[:2] for ln in lines] == [["streamid", "identify"], ["streamid", "export"]]
    for line in lines:
        p = subprocess.run([*STREAMID, *shlex.split(line)[1:]], cwd=tmp_path, capture_output=True, text=True,
                           timeout=180)
        assert p.returncode == 0, (line, p.stderr)
    assert "wrote damper.fmu (FMI 2.0 co-simulation" in p.stdout
    assert "binaries/linux64/damper.so" in zipfile.ZipFile(tmp_path / "damper.fmu").namelist()
    q = subprocess.run([sys.executable, "-c", block("python")], cwd=tmp_path, capture_output=True, text=True,
                       timeout=120)
    assert q.returncode == 0, q.stderr
    m = re.fullmatch(r"1499 samples, largest difference FMU - Model\.simulate: (\S+) N\n", q.stdout)
    assert m, q.stdout
    assert float(m.group(1)) <= 1e-6 * 140  # the damper's force spans about -70..70 N
