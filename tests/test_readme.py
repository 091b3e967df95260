"""The README's promises that can be checked here: its Python example runs, and its
command table names commands that exist."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _block_after(heading: str) -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index(heading)
    m = re.search(r"```python\n(.*?)```", text[start:], re.S)
    assert m, f"no python block after {heading!r}"
    return m.group(1)


def test_python_example_runs_and_finds_the_reactor_lags() -> None:
    code = _block_after("### From Python")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "'u': [[1, 2]]" in out.stdout  # the reactor's input lags, as the paper reports


def test_every_command_in_the_table_exists() -> None:
    from streamid.commands.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    text = README.read_text(encoding="utf-8")
    table = text[text.index("## What is in the box") : text.index("### From Python")]
    named = set(re.findall(r"^\| `streamid (\w+)", table, re.M))
    assert named, "no commands found in the README's table"
    assert named <= set(sub.choices), f"README names commands that do not exist: {named - set(sub.choices)}"
    assert set(sub.choices) <= named, f"commands missing from the README: {set(sub.choices) - named}"


def test_configuration_example_is_accepted_by_the_daemon() -> None:
    import tomllib

    from streamid.daemon.config import config_from_mapping

    text = README.read_text(encoding="utf-8")
    start = text.index("## Configuration")
    m = re.search(r"```toml\n(.*?)```", text[start:], re.S)
    assert m, "no toml block in the Configuration section"
    cfg = config_from_mapping(tomllib.loads(m.group(1)), "README.md")
    assert cfg is not None
