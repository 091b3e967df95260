"""``streamid status``: which daemon serves which stream, now, and how each stream is doing.

Asks every stream's status queryable (``streamid/<stream>/status``: only the daemon
serving a stream answers for it) and prints one line per stream: the daemon that
serves it (its id and the start of its life), the model version, the champion's
age and current free-run R² (and, re-judged on the newest held-out data, the share of samples its 90 % interval
covered, ``band cover``, and the share outside its estimation domain, ``outside``), the drift events so far, the stream's state, and the members sharing the
streams as that daemon sees them.  A stream of several outputs (MIMO: one champion per output) gets one more
line per output, indented, with that output's champion; a stream fed by ROS 2 topics one line per topic (messages
received, the bad ones by kind, samples waiting for the grid, the clock).  Network text is shown escaped.  Exit code 1 when
no stream answered within ``--timeout``.

Two answers for one stream (two daemons serving it, or a status forged by someone who may answer on the
bus: without access control anyone can) are a conflict: every answer is printed, its state column says
CONFLICT and names every daemon that answered, and a warning on standard error says so (exit code 3).
Two different answers claiming the same daemon and epoch (a replayed or forged copy: the daemon id and
epoch are public) are a conflict too; identical copies (one answer reaching us twice) count once.

What is not shown, counted and said on standard error: an answer whose document names another stream than
the key it came on, a document without a stream, an invalid document, and the answers beyond the bound of
one ask (at most 4096 answers, 16 MiB together, 1 MiB each: what a flood of answers can make status hold).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from streamid.wire.names import printable

__all__ = ["MAX_ANSWERS", "MAX_ANSWER_BYTES", "MAX_ANSWERS_BYTES", "Answers", "collect", "register", "run",
           "status_line", "output_lines", "ros2_lines"]

#: What one ``streamid status`` keeps of the answers: their number, their bytes together, the bytes of one
#: (a status document is a few kB); the rest is counted and said, never read.
MAX_ANSWERS = 4096
MAX_ANSWERS_BYTES = 16 * 1024 * 1024
MAX_ANSWER_BYTES = 1024 * 1024


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from streamid.transport import DEFAULT_ENDPOINT
    from streamid.commands.zenoh_flags import add_connection_flags

    p = sub.add_parser(
        "status",
        help="which daemon serves which stream, with each stream's model version and health",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--stream", default="*", metavar="NAME", help="stream to ask about (default: every stream)")
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    p.add_argument("--timeout", type=float, default=2.0, metavar="S",
                   help="how long to collect answers (default 2 s)")
    p.add_argument("--json", action="store_true", help="print each stream's status document as one JSON line")
    p.set_defaults(func=run)


def _num(v: Any, fmt: str) -> str:
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else "-"


def _table(doc: dict[str, Any], key: str) -> dict[str, Any]:
    value = doc.get(key)
    return value if isinstance(value, dict) else {}


def _outputs(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    models = doc.get("models")
    return {str(k): v for k, v in models.items() if isinstance(v, dict)} if isinstance(models, dict) else {}


def _share(v: Any) -> str:
    """A share in [0, 1] as a percentage (``91.2 %``); ``-`` for anything else (absent, or not a share)."""
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0
    return f"{100 * v:.1f} %" if ok else "-"


def _model_columns(version: Any, champ: dict[str, Any], drifts: Any) -> str:
    """The version, champion, FR R2 now, band cover, outside and drifts columns of the table (a stream's line and
    an output's): ``band cover`` the share of the newest held-out samples inside the champion's 90 % interval,
    ``outside`` the share of them outside its estimation domain (``-``: the status does not say)."""
    now = _table(champ, "current")
    return (f"v{_num(version, 'd'):<6} {_num(champ.get('age_s'), '.1f'):>8} s "
            f"{_num(now.get('r2_fr_val'), '.4f'):>9} {_share(now.get('interval_coverage_val')):>10} "
            f"{_share(now.get('outside_domain_val')):>7} {_num(drifts, 'd'):>6}")


def _who(doc: dict[str, Any]) -> tuple[str, int]:
    origin = _table(_table(doc, "daemon"), "origin")
    epoch = origin.get("epoch_ns")
    return str(origin.get("daemon", "?")), epoch if isinstance(epoch, int) and not isinstance(epoch, bool) else 0


def conflict_text(answers: list[dict[str, Any]]) -> str:
    """The state column of a stream answered by several daemons: CONFLICT, naming each (escaped)."""
    lives = Counter(_who(a) for a in answers)
    names = ", ".join(f"{d} (epoch {e})" + (f" {n} times with different content" if n > 1 else "")
                      for (d, e), n in sorted(lives.items()))
    why = ("one daemon life gives one answer: the others are replayed or forged" if len(lives) < len(answers)
           else "two daemons serve it, or one answer is forged")
    return printable(f"CONFLICT: {len(answers)} answers for this stream, from {names}: {why}", 400)


@dataclass
class Answers:
    """The status answers of one ask: per stream, each distinct answer; and what was not shown."""

    #: stream -> (daemon, epoch, payload) -> its document; identical payloads from one life count once
    docs: dict[str, dict[tuple[str, int, bytes], dict[str, Any]]] = field(default_factory=dict)
    invalid: int = 0
    #: documents without a ``stream``
    no_stream: int = 0
    #: documents naming another stream than the key they came on
    wrong_key: int = 0
    dropped: int = 0
    dropped_bytes: int = 0


def collect(replies: list[tuple[str, bytes]]) -> Answers:
    """Sort the ``(key, payload)`` replies of a status ask (:class:`Answers`; the drop counts are the caller's)."""
    from streamid.errors import ModelFormatError
    from streamid.wire.documents import parse_status
    from streamid.wire.keys import status_key

    out = Answers()
    for key, payload in replies:
        try:
            doc = parse_status(payload)
        except ModelFormatError:
            out.invalid += 1
            continue
        stream = doc.get("stream")
        if not isinstance(stream, str):
            out.no_stream += 1
            continue
        if key != status_key(stream):
            out.wrong_key += 1
            continue
        daemon, epoch = _who(doc)
        out.docs.setdefault(stream, {})[(daemon, epoch, bytes(payload))] = doc
    return out


def _notes(got: Answers) -> list[str]:
    """The lines on standard error saying what was not shown."""
    notes = []
    if got.invalid:
        notes.append(f"skipped {got.invalid} invalid status documents")
    if got.no_stream:
        notes.append(f"ignored {got.no_stream} status documents without a 'stream' (a daemon always names it)")
    if got.wrong_key:
        notes.append(f"ignored {got.wrong_key} answers whose document names another stream than the key they came "
                     "on (replayed or forged)")
    if got.dropped:
        notes.append(f"dropped {got.dropped} answers ({got.dropped_bytes} bytes) beyond what one ask reads "
                     f"({MAX_ANSWERS} answers, {MAX_ANSWERS_BYTES} bytes together, {MAX_ANSWER_BYTES} each): a "
                     "flood of answers, or ask one --stream at a time")
    return notes


def status_line(doc: dict[str, Any], conflict: str | None = None) -> str:
    """One line of the table for a parsed ``streamid.status/1`` document (escaped).

    A stream of several outputs shows no champion here (each output has its own: :func:`output_lines`)."""
    daemon, champ = _table(doc, "daemon"), _table(doc, "champion")
    if len(_outputs(doc)) > 1:
        champ = {}
    origin, sharing = _table(daemon, "origin"), _table(daemon, "sharing")
    members = sharing.get("members")
    members = members if isinstance(members, list) else []
    state = "DEGRADED: " + str(doc.get("degraded_reason", "")) if doc.get("degraded") else "ok"
    if conflict is not None:
        state = f"{conflict}; {state}"
    text = (f"{str(doc.get('stream', '?')):<20} {str(origin.get('daemon', '?')):<18} "
            f"{_model_columns(doc.get('version'), champ, doc.get('drifts'))} {next_update(doc):<20} "
            f"{backlog(doc):>12} {len(members) or 1:>7}  {state}")
    return printable(text, 400)


def next_update(doc: dict[str, Any]) -> str:
    """The next update column: ``refresh (run in 3/8)`` (the champion's weights re-solved; a coevolution run after 3
    more, one every 8 updates now) or ``coevolution`` (streamid.online.refresh); ``-`` when the status does not say."""
    r = _table(doc, "refresh")
    if r.get("next") == "refresh":
        return f"refresh (run in {_num(r.get('refreshes_before_coevolution'), 'd')}/{_num(r.get('coevolution_every'), 'd')})"
    return "coevolution" if r.get("next") == "coevolution" else "-"


def backlog(doc: dict[str, Any]) -> str:
    """The backlog column: windows waiting and the stream time from the oldest's end to the newest's (``3 / 2.0 s``;
    ``0`` when none waits; ``-`` when the status does not say): a stream falling behind shows here before any window
    is coalesced (docs/daemon.md, "Windows, updates, backlog")."""
    w = _table(doc, "windows")
    n, span = w.get("pending_windows"), w.get("backlog_s")
    if not isinstance(n, int) or isinstance(n, bool):
        return "-"
    return "0" if n == 0 else f"{n} / {_num(span, '.1f')} s"


def output_lines(doc: dict[str, Any]) -> list[str]:
    """Under a stream of several outputs, one line per output: its champion's version, age, current free-run R²
    and drifts, in the table's columns (escaped); none for a stream of one output."""
    outputs = _outputs(doc)
    if len(outputs) < 2:
        return []
    lines = []
    for name in sorted(outputs):
        out = outputs[name]
        columns = _model_columns(out.get("version"), _table(out, "champion"), out.get("drifts"))
        lines.append(printable(f"{'  ' + name:<20} {'':<18} {columns}", 400))
    return lines


def ros2_lines(doc: dict[str, Any]) -> list[str]:
    """Under a stream fed by ROS 2 topics (``[streams.X.ros2]``), one line per topic: messages received, the bad
    ones by kind (a payload that does not decode, a wrong type, a field missing or not a number, ...), the samples
    waiting for the grid and the clock that timed them (escaped); none for other streams."""
    topics = _table(_table(doc, "ros2"), "topics")
    lines = []
    for topic in sorted(topics):
        tp = topics[topic] if isinstance(topics[topic], dict) else {}
        bad = _table(tp, "bad")
        kinds = ", ".join(f"{k} {_num(v, 'd')}" for k, v in sorted(bad.items()))
        lines.append(printable(f"  ros2 {topic}: {_num(tp.get('received'), 'd')} received, {_num(tp.get('bad_total'), 'd')}"
                               f" bad{f' ({kinds})' if kinds else ''}, {_num(tp.get('pending'), 'd')} pending, "
                               f"clock {tp.get('clock') or '-'}", 400))
    return lines


HEADER = (f"{'stream':<20} {'served by':<18} {'version':<7} {'champion':>10} {'FR R2 now':>9} {'band cover':>10} "
          f"{'outside':>7} {'drifts':>6} "
          f"{'next update':<20} {'backlog':>12} {'daemons':>7}  state")


def run(args: argparse.Namespace) -> int:
    from streamid.commands.zenoh_flags import settings_from_args
    from streamid.errors import ConfigError
    from streamid.transport import Bus
    from streamid.wire.keys import PREFIX, check_stream_name, status_key

    if not args.timeout > 0:
        raise ConfigError(f"--timeout must be a number of seconds > 0; got {args.timeout}")
    key = f"{PREFIX}/*/status" if args.stream == "*" else status_key(check_stream_name(args.stream))
    settings = settings_from_args(args)
    if settings.connect_wait_s is None:  # a one-shot question: wait for the endpoint at most --timeout
        import dataclasses

        settings = dataclasses.replace(settings, connect_wait_s=args.timeout)
    with Bus(settings) as bus:
        replies = bus.get(key, timeout_s=args.timeout, all_replies=True, max_replies=MAX_ANSWERS,
                          max_bytes=MAX_ANSWERS_BYTES, max_reply_bytes=MAX_ANSWER_BYTES)
    got = collect(replies)
    got.dropped, got.dropped_bytes = replies.dropped, replies.dropped_bytes
    docs = got.docs
    conflicts = {name: conflict_text(list(a.values())) for name, a in docs.items() if len(a) > 1}
    if args.json:
        for name in sorted(docs):
            for _, doc in sorted(docs[name].items(), key=lambda kv: kv[0]):
                print(json.dumps(doc))
    else:
        print(HEADER)
        for name in sorted(docs):
            for _, doc in sorted(docs[name].items(), key=lambda kv: kv[0]):
                print(status_line(doc, conflicts.get(name)))
                for line in (*output_lines(doc), *ros2_lines(doc)):
                    print(line)
    for name in sorted(conflicts):
        print(f"streamid status: stream {printable(name, 80)}: {conflicts[name]} (see docs/security.md)", file=sys.stderr)
    for note in _notes(got):
        print(f"streamid status: {note}", file=sys.stderr)
    if not docs:
        where = ", ".join(settings.connect) or ", ".join(settings.listen) or "the --zenoh-config endpoints"
        print(f"streamid status: no stream answered at {where} within {args.timeout:g} s", file=sys.stderr)
        return 1
    return 3 if conflicts else 0
