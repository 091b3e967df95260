"""Errors that point at the fix, and flags that mean one thing on every command (issue 14).

Real subprocesses and real Zenoh sessions on loopback (explicit tcp/127.0.0.1 endpoints, multicast off).
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import endpoint, free_tcp_port
from streamid.commands.main import build_parser, main
from streamid.transport import Bus, ZenohSettings

STREAMID = [sys.executable, "-m", "streamid"]


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return dict(sub.choices)  # type: ignore[arg-type]


def test_help_shows_no_restructuredtext_markup() -> None:
    cmds = _subparsers()
    assert {"identify", "daemon", "watch", "demo", "router", "bench", "record", "replay", "simulate"} <= set(cmds)
    for name, p in cmds.items():
        text = p.format_help()
        for markup in ("``", "\n::", ":class:", ":func:", "--------\n"):
            assert markup not in text, f"streamid {name} --help shows {markup!r}"
    assert "Examples:" in cmds["identify"].format_help()


def test_a_command_alone_gets_the_parser_it_gets_among_all() -> None:
    """``streamid NAME ...`` imports NAME's module only (build_parser(NAME)); its parser must be the one the full
    parser has (every command's name is its module's or its entry point's), and the rest still list them all."""
    full = _subparsers()
    for name, p in full.items():
        sub = next(a for a in build_parser(name)._actions if a.dest == "command")
        assert list(sub.choices) == [name], name  # type: ignore[arg-type]
        assert sub.choices[name].format_help() == p.format_help(), name  # type: ignore[index]
    for other in (None, "nope", "--version"):
        sub = next(a for a in build_parser(other)._actions if a.dest == "command")
        assert set(sub.choices) == set(full), other  # type: ignore[arg-type]


def test_json_means_one_json_line_on_stdout_everywhere_and_files_use_report() -> None:
    for name, p in _subparsers().items():
        for a in p._actions:
            if "--json" in a.option_strings:
                assert a.nargs == 0, f"streamid {name} --json must take no value (it prints JSON on stdout)"
                assert "JSON line" in (a.help or ""), f"streamid {name} --json help: {a.help!r}"
            if "--report" in a.option_strings:
                assert a.nargs is None and "JSON file" in (a.help or ""), name


def test_bench_only_lists_its_sections(capsys: pytest.CaptureFixture[str]) -> None:
    help_text = " ".join(_subparsers()["bench"].format_help().split())
    assert "sections: capacity, daemon, engine, logs, long, mr, online, peers, reading, suite" in help_text
    assert main(["bench", "--only", "engin"]) == 2
    err = capsys.readouterr().err
    assert "--only takes one of capacity, daemon, engine, logs, long, mr, online, peers, reading, suite; got 'engin' (did you mean 'engine'?)" in err


def test_replay_unknown_log_lists_the_bundled_logs_and_the_closest(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", "mr_dampr", "--connect", endpoint()]) == 2
    err = capsys.readouterr().err
    assert "no file 'mr_dampr'" in err and "'mr_damper', 'piezo_p885', 'piezo_sim_20khz'" in err
    assert "did you mean 'mr_damper'?" in err


def test_replay_with_no_subscriber_says_so_and_fails_when_required() -> None:
    ep = endpoint()
    args = [*STREAMID, "replay", "mr_damper", "--connect", ep, "--max-speed", "--end", "0.2", "--wait-subscribers", "0.2"]
    with Bus(ZenohSettings(mode="router", listen=(ep,))):  # a network that answers, with no subscriber on it
        p = subprocess.run([*args, "--require-subscriber"], capture_output=True, text=True, timeout=60)
        assert p.returncode == 1, p.stderr
        last = p.stdout.strip().splitlines()[-1]
        assert last.startswith(f"no subscriber via {ep} on streamid/mr_damper/samples: nothing received these messages")
        q = subprocess.run([*args, "--json"], capture_output=True, text=True, timeout=60)
        assert q.returncode == 0, q.stderr  # without --require-subscriber: reported, not an error
        assert json.loads(q.stdout.strip().splitlines()[-1])["unheard_keys"] == ["streamid/mr_damper/samples"]
    r = subprocess.run([*args, "--connect-wait", "0.5"], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and f"cannot connect to {ep}" in r.stderr  # nothing answers: said, not hung


def test_watch_names_the_endpoint_and_fails_when_nothing_came() -> None:
    ep = endpoint()
    p = subprocess.run([*STREAMID, "watch", "--connect", ep, "--duration", "1"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 1
    assert f"nothing reachable at {ep} yet" in p.stderr
    assert f"no model received from {ep} in 1 s" in p.stderr.strip().splitlines()[-1]


@pytest.mark.parametrize("command", ["daemon", "router"])
def test_address_in_use_is_one_sentence_with_the_endpoint_and_the_flag(command: str) -> None:
    port = free_tcp_port()
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", port))
        busy.listen()
        extra = ["--no-rerun", "--duration", "2"] if command == "daemon" else ["--duration", "2"]
        p = subprocess.run([*STREAMID, command, "--listen", f"tcp/127.0.0.1:{port}", *extra],
                           capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, (p.stdout, p.stderr)
    err = p.stderr.strip()
    assert err.startswith(f"streamid {command}: error: cannot listen on tcp/127.0.0.1:{port}: the address is already in use")
    assert "--listen" in err and ".rs" not in err and "cargo" not in err
    assert len(err.splitlines()) == 1, err


@pytest.mark.parametrize(("words", "usage", "error"), [
    (["status", "nosuch"], "usage: streamid status ", "streamid status: error: unrecognized arguments: nosuch"),
    (["simulate", "mr_damper", "x.mcap", "--change", "3"], "usage: streamid simulate ",
     "streamid simulate: error: unrecognized arguments: --change 3"),
    (["--bogus"], "usage: streamid [-h]", "streamid: error: unrecognized arguments: --bogus"),
])
def test_an_unknown_argument_is_refused_by_the_command_it_was_given_to(
        words: list[str], usage: str, error: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The command's own usage, not the top level's, shows what it accepts (before: ``streamid status nosuch``
    printed ``usage: streamid [-h] [--version] COMMAND ...``, which lists no option of status)."""
    with pytest.raises(SystemExit) as info:
        main(words)
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.startswith(usage) and error in err, err


def test_a_reader_that_went_away_ends_the_command_quietly(tmp_path: Path) -> None:
    """``streamid ... | head``: once standard output's reader has gone, the command stops with 141 (128 + SIGPIPE,
    what a shell reports) and no traceback; its work is done (the log is written)."""
    out = tmp_path / "d.mcap"
    p = subprocess.Popen([*STREAMID, "simulate", "mr_damper", str(out), "--duration", "1"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # before the command has written anything: its one line meets a closed pipe
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 141 and "Traceback" not in err and "BrokenPipe" not in err, err
    assert out.is_file() and out.stat().st_size > 0
