"""The README's promises that can be checked here: every runnable block runs as printed (only the
endpoint changed to a free loopback port), its command table names the commands that exist, and
its explanation of the output covers every figure printed."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import endpoint, free_tcp_port, require
from hosts import Host, Network, Proc, open_network, wait_listening

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
STREAMID = [sys.executable, "-m", "streamid"]
README_ENDPOINT = "tcp/127.0.0.1:7447"
SEVERAL = "## More than one machine"
SECOND_RECORD = "### Judge a model on a record it has never seen"
LAB = "## 4. Your lab's logs"
#: Upper bounds of the waits of the several-machines recipe: a process up, the first models at the watcher.
UP_S, MODELS_S = 30.0, 60.0
#: Lines of `streamid watch`: which daemon serves a stream (stream, daemon id), a model (stream).
ORIGIN_LINE = r"^(\S+): (?:a new daemon life: )?models from daemon (\w+), life began \S+$"
MODEL_LINE = r"^(\S+) v\d+ (?:cold G=|warm G=|refreshed)"

#: Shell blocks the tests do not run, and why (every other block is run below).
NOT_RUN = {
    "pip install . && streamid demo": "a minute of real time; tests/test_demo.py runs it with --loops 1 (about 30 s)",
    "pip install '.[test]' && pytest": "the test suite itself (CI runs it in a fresh virtual environment)",
    "pip install '.[peers]' && streamid bench --peers --repeat 5": "minutes of benchmarks",
    "streamid identify mr_damper --generations 20 --model damper_model.json": "run as printed, with the fmpy "
    "block after it, by tests/test_export_readme.py",
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
    fr_unseen = float(out.stdout.splitlines()[2])  # assess() on another experiment of the reactor
    assert 0.99 < fr_unseen <= 1.0, out.stdout


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
    run = {_block_after(h, "sh", k).strip() for h, k in (("## 1. Your own data file", 0), (SECOND_RECORD, 0),
                                                        ("## 2. Replay a log", 0),
                                                        ("## 2. Replay a log", 1), ("## 3. Inspect residuals", 0),
                                                        (SEVERAL, 0), (LAB, 0))}
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
    assert re.fullmatch(r"kept: run 0 \(marked \*; chosen by fr_est on the estimation data\): force_N\(t\) = "
                        r"(median of [3-8] networks on )?F\[.+\]( \(the union of their lags\))?", kept)
    assert "caveat" in explained and "caveat:" not in p.stdout  # explained, and the damper's model raises none
    combined = next(ln for ln in p.stdout.splitlines() if ln.startswith("restarts combined: "))
    assert re.fullmatch(r"restarts combined: kept the median of the [3-8] finished restarts' networks \([\d, ]+\), FR R2 "
                        r"est 0\.\d{5}; each finished as a kept model is: weights refined to the "
                        r"free run in \d \(held out: refined on the first half, kept if the second half's FR R2 rose\)",
                        combined)  # the damper's kept network has no long linear part: the median is the model
    assert "restarts combined" in explained and "median" in kept  # the README says what that line means
    direct = next(ln for ln in p.stdout.splitlines() if ln.startswith("direct terms u(t) are "))
    assert re.fullmatch(r"direct terms u\(t\) are (not )?candidates: .+ \(likelihood ratio of u\(t\) in a linear ARX model "
                        r"of order \d+: velocity_cm_s [0-9.]+; threshold 10\.83\)", direct)
    assert "direct terms" in explained
    linear = next(ln for ln in p.stdout.splitlines() if ln.startswith("direct linear part a'r + b: "))
    assert re.fullmatch(r"direct linear part a'r \+ b: ((not )?kept|in \d of the \d networks) \(every candidate was offered with and without one, "
                        r"the kind chosen by aic\)", linear)
    assert "direct linear part" in explained and linear in section  # the README shows the real line and explains it
    longlin = next(ln for ln in p.stdout.splitlines() if ln.startswith("long linear part"))
    assert longlin == "long linear part: not tried (the networks' estimation FR R2 is at least 0.95)", longlin
    assert "long linear part" in explained and longlin in section
    band = next(ln for ln in p.stdout.splitlines() if ln.startswith("interval: "))  # issue 51: the model's band
    assert re.fullmatch(r"interval: the 90 % free-run band covers \d+\.\d % of the validation samples, mean width "
                        r"[0-9.]+ \([0-9.]+ of the output's standard deviation\); its width: \d+ % from the error's scale"
                        r"(, \d+ % from the networks' disagreement)?(, \d+ % from the distance beyond the estimation "
                        r"domain)?(; under 80 %: .+)?", band), band
    assert "The line ends with what makes the band wide" in section  # and the README says how to read that part
    domain = next(ln for ln in p.stdout.splitlines() if ln.startswith("estimation domain: "))
    assert "interval" in explained and "estimation domain" in explained and domain in section
    assert (work / "mr_damper.json").is_file()
    q = subprocess.run([sys.executable, "-c", _block_after("## 1. Your own data file")], cwd=work,
                       capture_output=True, text=True, timeout=60)
    assert q.returncode == 0, q.stderr
    assert re.match(r"RBF-NARX (model|ensemble \(median of \d networks\)) velocity_cm_s -> force_N\n  regressors  "
                    r"force_N\(t-1", q.stdout), q.stdout[:200]
    rms = float(re.search(r"validation part: ([0-9.]+) N", q.stdout).group(1))  # type: ignore[union-attr]
    assert 0 < rms < 20  # the MR damper's force spans about -70..70 N


def test_journey_1b_a_model_judged_on_another_record(tmp_path: Path) -> None:
    """The README's second experiment, each line run as printed: identify --validate, then validate agrees."""
    work = _workdir(tmp_path)
    block = _block_after(SECOND_RECORD, "sh")
    outs = []
    for line in [ln for ln in block.splitlines() if ln.strip()]:
        p = subprocess.run(_command(line, endpoint()), cwd=work, capture_output=True, text=True, timeout=180)
        assert p.returncode == 0, (line, p.stderr)
        outs.append(p.stdout)
    identified, validated = outs[2], outs[3]
    assert "data      estimation all 6000 samples of damper_a.mcap, validation all 6000 of damper_b.mcap" in identified
    best = next(ln for ln in identified.splitlines() if re.match(r"^\s+\d+\*", ln)).split()
    fr_val, osa_val = best[8], best[6]  # the kept run's FR val and OSA val columns
    free = next(ln for ln in validated.splitlines() if ln.startswith("  free run "))
    one = next(ln for ln in validated.splitlines() if ln.startswith("  one step ahead "))
    assert free.split()[2] == fr_val and one.split()[3] == osa_val, (free, one, best)
    assert re.search(rf"^passed: free-run R² {fr_val} >= --min-r2-fr 0.9$", validated, re.M), validated
    section = _section(SECOND_RECORD)
    for line in validated.splitlines()[:4]:  # the README shows the real header lines (its figures are one run's)
        if line.startswith(("  read", "streamid validate:")):
            assert line in section, line
    for term in ("fit %", "RMSE", "--min-r2-fr"):
        assert term in validated and (f"**{term}**" in section or f"**`{term}`**" in section), term


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
        loop = subprocess.run([sys.executable, "-c", _block_after("### Use the served model in a control loop")],
                              cwd=work, capture_output=True, text=True, timeout=90)
        assert loop.returncode == 0, loop.stderr
        # what it printed is the received model's own one-step prediction and free run on those samples
        live = Model.load(work / "mr_damper_live.json")
        data = np.loadtxt(ROOT / "examples" / "data" / "mr_damper.csv", delimiter=",", skiprows=1)
        u, y = data[:, 1], data[:, 2]
        osa = live.predict_osa(u[:401], y[:401])[-1]
        assert f"next force {osa:.1f} N, measured {y[400]:.1f} N" in loop.stdout, loop.stdout
        fr = live.simulate(u[400 - live.max_lag : 600], y[400 - live.max_lag : 400])[live.max_lag :]
        r2 = 1 - np.sum((fr - y[400:600]) ** 2) / np.sum((y[400:600] - y[400:600].mean()) ** 2)
        assert f"1 s forecast R2 {r2:.3f}" in loop.stdout, loop.stdout
        beyond = re.findall(r"^beyond the model's range: (.+)$", loop.stdout, re.M)
        assert beyond and (beyond[0] == "nothing" or set(re.findall(r"'([^']+)'", beyond[0])) <= {"velocity_cm_s",
                                                                                                   "force_N"}), loop.stdout
        # the steps are the same free run, with the model's 90 % band (when it carries an interval)
        L = live.max_lag
        if live.interval is not None:
            band = live.simulate(u[400 - L : 600], y[400 - L : 400], interval=0.9)
            stepped = f"stepped 1 s: {band.y[-1]:.1f} N, 90 % band {band.lower[-1]:.1f} .. {band.upper[-1]:.1f} N, in"
        else:
            stepped = f"stepped 1 s: {fr[-1]:.1f} N, 90 % band none (no interval), in"
        assert stepped in loop.stdout, loop.stdout
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
    assert files and files[0].endswith("mr_damper.rrd") and plan["command"][-len(files):] == files[::-1]
    assert not plan["no_footer"]
    check = subprocess.run(["rerun", "rrd", "verify", *files], cwd=work, capture_output=True, text=True, timeout=60)
    assert f"{len(files)} file" in check.stdout + check.stderr and check.returncode == 0, (check.stdout, check.stderr)


# --------------------------------------------------------------------------- More than one machine
def _machines(lines: list[str]) -> list[tuple[str, list[str]]]:
    """The recipe's commands in order, each with the machine it runs on: the certificates and the router on
    "router", each daemon on its own machine, the publishers on "sensor", the watcher on "analyst"."""
    out, n = [], 0
    for line in lines:
        argv = shlex.split(line, comments=True)
        what = argv[1] if argv[0] == "streamid" else argv[0]
        if what == "daemon":
            n += 1
        machine = {"sh": "router", "router": "router", "daemon": f"daemon{n}", "replay": "sensor",
                   "watch": "analyst"}[what]
        out.append((machine, argv))
    return out


def _published(argv: list[str]) -> str:
    """The stream a ``streamid replay`` command publishes (its ``--stream NEW``, else the log's name)."""
    names = [argv[i + 1] for i, a in enumerate(argv) if a == "--stream"]
    return names[0] if names else argv[2]


@pytest.mark.parametrize("kind", ["loopback", pytest.param("netns", marks=pytest.mark.alone)])  # fixed namespaces
def test_several_machines_recipe_runs_as_printed(kind: str, tmp_path: Path) -> None:
    """The README's router recipe (TLS + access control) with every machine a directory of its own holding
    examples/zenoh/ (on loopback, or each in its own network namespace): only ROUTER and the port replaced."""
    require("openssl")
    if kind == "netns":
        require("netns")
    block = _block_after(SEVERAL, "sh")
    lines = [ln.strip() for ln in block.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    sample = _section(SEVERAL).split("**It works**", 1)[1].split("```", 2)[1]  # the README's sample of watch's output
    shown = [ln.strip() for ln in sample.splitlines() if ln.strip()]
    assert re.fullmatch(ORIGIN_LINE, shown[0]) and re.match(MODEL_LINE, shown[1]), shown  # the lines checked below
    n_daemons = sum(shlex.split(ln)[:2] == ["streamid", "daemon"] for ln in lines)
    assert n_daemons >= 2, lines
    with open_network(kind, n_daemons + 2) as net:
        port = 7447 if kind == "netns" else free_tcp_port()  # a namespace has its own ports
        lines = [ln.replace("ROUTER", net.router.address).replace(":7447", f":{port}") for ln in lines]
        hosts = {"router": net.router, "sensor": net.hosts[-2], "analyst": net.hosts[-1],
                 **{f"daemon{i + 1}": h for i, h in enumerate(net.hosts[:n_daemons])}}
        for name in hosts:  # each machine has the repository's examples/zenoh/ (and no certificate yet)
            shutil.copytree(ROOT / "examples" / "zenoh", tmp_path / name / "examples" / "zenoh",
                            ignore=lambda d, names: [n for n in names if n.endswith((".pem", ".key"))])
        seconds = _run_recipe(net, hosts, _machines(lines), port, tmp_path)
    print(f"\nREADME recipe ({kind}, TLS + ACL): sensors started -> first model at the watcher: "
          + ", ".join(f"{s} {v:.1f} s" for s, v in seconds.items()))


def _run_recipe(net: Network, hosts: dict[str, Host], recipe: list[tuple[str, list[str]]], port: int,
                tmp_path: Path) -> dict[str, float]:
    procs: dict[str, list[Proc]] = {}
    daemon_ids: dict[str, str] = {}
    served: dict[str, str] = {}  # stream -> daemon id, for daemons whose command names their streams
    t0 = 0.0
    for i, (machine, argv) in enumerate(recipe):
        host, cwd = hosts[machine], tmp_path / machine
        what = argv[1] if argv[0] == "streamid" else argv[0]
        if what == "sh":  # the certificates, then ca.pem copied to every other machine
            done = host.exec(argv, cwd=cwd)
            assert done.returncode == 0, done.stderr
            for other in set(hosts) - {machine}:
                shutil.copy(cwd / "examples/zenoh/certs/ca.pem", tmp_path / other / "examples/zenoh/certs/ca.pem")
            continue
        if what == "replay" and not t0:
            t0 = time.monotonic()
        proc = host.run([*STREAMID, *argv[1:]], tmp_path / f"{i}-{machine}-{what}.log", cwd=cwd)
        procs.setdefault(what, []).append(proc)
        if what == "router":
            assert wait_listening(proc, UP_S) == [f"tcp/{net.router.address}:{port}"], proc.text()
        elif what == "daemon":
            m = proc.wait_for(r"serving on \S+ as daemon (\w+)", UP_S)
            assert m is not None, proc.text()
            daemon_ids[proc.name] = m.group(1)
            served.update({argv[k + 1]: m.group(1) for k, a in enumerate(argv) if a == "--stream"})
        elif what == "watch":
            assert proc.wait_for(r"waiting for models", UP_S) is not None, proc.text()
    streams = {_published(argv) for machine, argv in recipe if machine == "sensor"}
    assert len(streams) >= 2 and set(served) <= streams, (streams, served)
    (watch,) = procs["watch"]
    first: dict[str, float] = {}
    deadline = time.monotonic() + MODELS_S
    while set(first) < streams and time.monotonic() < deadline:
        for s in re.findall(MODEL_LINE, watch.text(), re.M):
            first.setdefault(s, time.monotonic() - t0)
        time.sleep(0.1)
    listening = {name: h.listening([p.pid for p in h.procs]) for name, h in hosts.items()}
    codes = {p.name: p.stop() for what in ("replay", "watch", "daemon", "router") for p in procs[what]}
    text = watch.text()
    assert set(first) == streams, (text[-3000:], {p.name: p.text()[-1500:] for p in procs["daemon"]})
    origins = re.findall(ORIGIN_LINE, text, re.M)
    for stream in streams:  # served by the daemon whose command names it; else by the daemons of the recipe
        got = {d for s, d in origins if s == stream}  # (sharing them may move a stream when a daemon joins)
        assert (got == {served[stream]}) if stream in served else (got and got <= set(daemon_ids.values())), \
            (stream, origins, served, daemon_ids)
    for p in procs["replay"]:
        assert "no subscriber" not in p.text(), p.text()
    assert all(code == 0 for code in codes.values()), (codes, {p.name: p.text()[-1500:] for ps in procs.values()
                                                               for p in ps})
    assert [f"{ls.proto}/{ls.local}" for ls in listening["router"]] == [f"tcp/{net.router.address}:{port}"]
    assert all(not listening[m] for m in hosts if m != "router"), listening  # nobody else listens anywhere
    return first


def test_journey_4_your_labs_logs_each_line_as_printed(tmp_path: Path) -> None:
    """The lab's files, written by asammdf and rosbags (tests/lab_files.py), identified and converted by the
    README's lines as printed; the sample output it shows is the real one."""
    import lab_files

    from streamid.logs import read_log_arrays

    lab_files.write_mf4(tmp_path / "bench.mf4")
    lab_files.write_bag(tmp_path / "robot_bag", "mcap")
    outs = []
    for line in [ln for ln in _block_after(LAB, "sh").splitlines() if ln.strip()]:
        p = subprocess.run(_command(line, endpoint()), cwd=tmp_path, capture_output=True, text=True, timeout=180)
        assert p.returncode == 0, (line, p.stderr)
        assert "Traceback" not in p.stderr, p.stderr
        outs.append(p)
    blocks = re.findall(r"^```(\w*)\n(.*?)^```$", _section(LAB), re.S | re.M)
    shown = next(text for lang, text in blocks if not lang).splitlines()  # the README's sample output
    real = (outs[0].stderr + outs[0].stdout).splitlines()
    for line in shown:
        assert line in real, (line, real[:6])
    for p, model in zip(outs[:2], ("bench.json", "robot.json")):
        best = next(ln for ln in p.stdout.splitlines() if re.match(r"^\s+\d+\*", ln)).split()
        assert float(best[8]) > 0.95, p.stdout  # FR val: the plant behind both files is identified
        assert (tmp_path / model).is_file()
    assert "clock '/joint_states:velocity[2]' (period 10 ms)" in outs[1].stdout
    arr = read_log_arrays(tmp_path / "robot.mcap")
    assert arr.stream == "robot_bag" and len(arr) == 2000 and list(arr.outputs) == ["/joint_states:velocity[2]"]
