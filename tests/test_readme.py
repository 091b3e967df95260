"""The README's promises that can be checked here: every runnable block runs as printed (only the
endpoint changed to a free loopback port), its command table names the commands that exist, and
its explanation of the output covers every figure printed."""

from __future__ import annotations

import json
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

from conftest import endpoint

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
STREAMID = [sys.executable, "-m", "streamid"]
README_ENDPOINT = "tcp/127.0.0.1:7447"

#: Shell blocks the tests do not run, and why (every other block is run below).
NOT_RUN = {
    "pip install . && streamid demo": "a minute of real time; CI runs the demo's own test and the command parses",
    "pip install '.[test]' && pytest": "the test suite itself (CI runs it in a fresh virtual environment)",
    "streamid router --listen tcp/0.0.0.0:7447": "several machines (tests/test_router.py covers the topology)",
    "pip install '.[peers]' && streamid bench --peers --repeat 5": "minutes of benchmarks",
}


def _block_after(heading: str, lang: str = "python", skip: int = 0) -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index(heading)
    blocks = re.findall(rf"```{lang}\n(.*?)```", text[start:], re.S)
    assert len(blocks) > skip, f"no {lang} block {skip} after {heading!r}"
    return str(blocks[skip])


def _section(heading: str) -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index(heading)
    end = text.find("\n## ", start + len(heading))
    return text[start : end if end > 0 else len(text)]


def _command(block: str, ep: str) -> list[str]:
    """The one command of a shell block, as argv for this interpreter (``streamid`` -> ``python -m streamid``)."""
    lines = [ln for ln in block.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    assert len(lines) == 1, f"expected one command, got {lines}"
    argv = shlex.split(lines[0].replace(README_ENDPOINT, ep), comments=True)
    assert argv[0] in ("streamid", "rerun"), argv
    return [*STREAMID, *argv[1:]] if argv[0] == "streamid" else argv


def _workdir(tmp_path: Path) -> Path:
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    return tmp_path


def test_python_example_runs_and_finds_the_reactor_lags() -> None:
    code = _block_after("## The engine from Python")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "'u': [[1, 2]]" in out.stdout  # the reactor's input lags, as the paper reports


def test_every_command_in_the_table_exists() -> None:
    from streamid.commands.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    text = README.read_text(encoding="utf-8")
    table = text[text.index("## What is in the box") : text.index("## The engine from Python")]
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


def test_every_shell_block_is_run_or_listed_with_a_reason() -> None:
    text = README.read_text(encoding="utf-8")
    blocks = [b.strip() for b in re.findall(r"```sh\n(.*?)```", text, re.S)]
    run = {_block_after(h, "sh", k).strip() for h, k in (("## 1. Your own data file", 0), ("## 2. Replay a log", 0),
                                                        ("## 2. Replay a log", 1), ("## 3. Inspect residuals", 0))}
    for b in blocks:
        first = b.splitlines()[0].split("#")[0].strip()
        assert b in run or first in NOT_RUN, f"README shell block neither run by the tests nor listed in NOT_RUN: {b!r}"
    demo = subprocess.run([*STREAMID, "demo", "--help"], capture_output=True, text=True, timeout=60)
    assert demo.returncode == 0 and "about a minute" in demo.stdout
    assert text.index("pip install . && streamid demo") < text.index("## What it does")  # the two commands come first


def test_readme_opens_with_the_two_commands_and_leaves_the_lead_section() -> None:
    text = README.read_text(encoding="utf-8")
    heads = re.findall(r"^## (.+)$", text, re.M)
    assert heads[:6] == ["Two commands", "What it does", "1. Your own data file",
                         "Online identification in Python, without Zenoh",
                         "2. Replay a log and subscribe to live models from your code", "3. Inspect residuals in Rerun"]
    body = _section("## Online identification in Python, without Zenoh").split("\n", 1)[1].strip()
    assert "OnlineIdentifier" in body and "```python" in body  # its code: tests/test_online_identifier.py
    for doc in ("docs/method.md", "docs/benchmarks.md", "docs/reliability.md"):
        assert f"]({doc})" in text and (ROOT / doc).is_file(), doc
    assert "| section | case" not in text  # the benchmark tables live in docs/benchmarks.md


def test_journey_1_identify_a_csv_and_read_the_output(tmp_path: Path) -> None:
    work = _workdir(tmp_path)
    p = subprocess.run(_command(_block_after("## 1. Your own data file", "sh"), endpoint()), cwd=work,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    section = _section("## 1. Your own data file")
    header = next(ln for ln in p.stdout.splitlines() if ln.lstrip().startswith("run "))
    assert header in section, "the README's sample output must show the real column header"
    explained = " ".join(re.findall(r"^- \*\*(.+?)\*\*", section, re.M))  # the bold terms of "How to read it"
    for column in ("seconds", "evals", "fitness", "OSA est", "OSA val", "FR est", "FR val", "lags"):
        assert column in header and column in explained, column
    for name in ("ee", "ue", "e_eu", "u2_e", "u2_e2"):  # every test is printed with its verdict and explained
        assert re.search(rf"^  {name} (pass \(|FAIL: )", p.stdout, re.M), name
        assert f"`{name}`" in section, name
    kept = next(ln for ln in p.stdout.splitlines() if ln.startswith("kept: "))
    assert re.fullmatch(r"kept: run 0 \(marked \*; chosen by fr_est on the estimation data\): force_N\(t\) = F\[.+\]", kept)
    assert (work / "mr_damper.json").is_file()
    q = subprocess.run([sys.executable, "-c", _block_after("## 1. Your own data file")], cwd=work,
                       capture_output=True, text=True, timeout=60)
    assert q.returncode == 0, q.stderr
    assert q.stdout.startswith("RBF-NARX model velocity_cm_s -> force_N\n  regressors  force_N(t-1")
    rms = float(re.search(r"validation part: ([0-9.]+) N", q.stdout).group(1))  # type: ignore[union-attr]
    assert 0 < rms < 20  # the MR damper's force spans about -70..70 N


def test_journeys_2_and_3_replay_subscribe_and_open_the_rrd(tmp_path: Path) -> None:
    work = _workdir(tmp_path)
    ep = endpoint()
    daemon = subprocess.Popen(_command(_block_after("## 2. Replay a log", "sh", 0), ep), cwd=work,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    replay = None
    try:
        assert daemon.stdout is not None
        line = daemon.stdout.readline()  # "streamid daemon: serving on ...": it listens
        assert f"serving on {ep}" in line, line
        replay = subprocess.Popen(_command(_block_after("## 2. Replay a log", "sh", 1), ep), cwd=work,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        code = _block_after("## 2. Replay a log").replace(README_ENDPOINT, ep)
        client = subprocess.run([sys.executable, "-c", code], cwd=work, capture_output=True, text=True, timeout=90)
        assert client.returncode == 0, client.stderr
        rows = re.findall(r"^v(\d+) (champion|rejected \((?:not_better|validation)\)): free-run R2 (-?[0-9.]+)  force_N\(t-",
                          client.stdout, re.M)
        champions = [int(v) for v, what, _ in rows if what == "champion"]
        assert champions[:1] == [1] and champions == sorted(set(champions)), client.stdout
        assert len(rows) >= 3 and all(float(r2) >= 0.9 for v, what, r2 in rows if what == "champion"), client.stdout
        assert "RBF-NARX model velocity_cm_s -> force_N" in client.stdout
        from streamid import Model

        assert Model.load(work / "mr_damper_live.json").output_name == "force_N"
        out, err = replay.communicate(timeout=60)
        assert replay.returncode == 0 and out.startswith("replayed 175 messages"), (out, err)
        assert "no subscriber" not in out
    finally:
        for proc in (replay, daemon):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT)  # Ctrl-C, as the README says
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    assert daemon.returncode == 0
    # journey 3: `streamid view mr_damper.rrd` opens a viewer on every segment; here the same command prints the
    # viewer command it would run, and every segment it names is checked by the rerun CLI
    argv = _command(_block_after("## 3. Inspect residuals", "sh"), ep)
    assert argv[-2:] == ["view", "mr_damper.rrd"]
    shown = subprocess.run([*argv, "--print-command", "--json"], cwd=work, capture_output=True, text=True,
                           timeout=60)
    assert shown.returncode == 0, shown.stderr
    plan = json.loads(shown.stdout)
    files = plan["files"]
    assert files and files[0].endswith("mr_damper.rrd") and plan["command"][-len(files):] == files and not plan["no_footer"]
    check = subprocess.run(["rerun", "rrd", "verify", *files], cwd=work, capture_output=True, text=True, timeout=60)
    assert f"{len(files)} file" in check.stdout + check.stderr and check.returncode == 0, (check.stdout, check.stderr)
