"""Security, static checks: nothing is unpickled or evaluated; listeners bind loopback.

- no module of ``streamid/``, ``recorders/``, ``replay/`` imports a pickle-family
  module, calls ``eval``/``exec``, calls ``numpy.load`` without ``allow_pickle=False``
  or passes ``allow_pickle`` other than ``False`` (an ``ast`` scan; the scanner is
  itself tested on code it must flag);
- the default endpoint and the defaults of every command's Zenoh flags are loopback,
  a session built from no flags listens nowhere, the Rerun server binds loopback, and
  no source string is a bind-all address.

The live Zenoh security tests are in ``test_security.py``.
"""

from __future__ import annotations

import argparse
import ast
import ipaddress
import json
from pathlib import Path

import pytest

from streamid.transport import DEFAULT_ENDPOINT
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args

ROOT = Path(__file__).resolve().parents[1]
SCANNED_PACKAGES = ("streamid", "recorders", "replay")


# --------------------------------------------------------------------------- static: no unpickling
#: Modules whose whole purpose is (un)pickling or loading code objects.
BANNED_MODULES = frozenset({"pickle", "_pickle", "cPickle", "cloudpickle", "dill", "shelve", "marshal", "joblib"})
#: Builtins that evaluate text as code.
BANNED_BUILTINS = frozenset({"eval", "exec"})
#: Attribute calls that unpickle whatever they are given.
BANNED_ATTRIBUTES = frozenset({"read_pickle"})


def scan_source(source: str, filename: str = "<string>") -> list[str]:
    """Unsafe (de)serialisation or evaluation in ``source``, as ``file:line: what`` strings."""
    tree = ast.parse(source, filename=filename)
    numpy_names = {"numpy"}  # names bound to the numpy module
    numpy_load_names: set[str] = set()  # names bound to numpy.load
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            numpy_names |= {a.asname or a.name for a in node.names if a.name == "numpy"}
        elif isinstance(node, ast.ImportFrom) and node.module == "numpy":
            numpy_load_names |= {a.asname or a.name for a in node.names if a.name == "load"}
    found: list[str] = []

    def flag(node: ast.AST, what: str) -> None:
        found.append(f"{filename}:{getattr(node, 'lineno', 0)}: {what}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in BANNED_MODULES:
                    flag(node, f"import {a.name}")
        elif isinstance(node, ast.ImportFrom):
            if (node.module or "").split(".")[0] in BANNED_MODULES:
                flag(node, f"from {node.module} import ...")
        elif isinstance(node, ast.Call):
            func = node.func
            if isinstance(func, ast.Name) and func.id in BANNED_BUILTINS:
                flag(node, f"{func.id}(...)")
            if isinstance(func, ast.Attribute) and func.attr in BANNED_BUILTINS \
                    and isinstance(func.value, ast.Name) and func.value.id == "builtins":
                flag(node, f"builtins.{func.attr}(...)")
            if isinstance(func, ast.Attribute) and func.attr in BANNED_ATTRIBUTES:
                flag(node, f".{func.attr}(...)")
            is_np_load = (
                (isinstance(func, ast.Attribute) and func.attr == "load"
                 and isinstance(func.value, ast.Name) and func.value.id in numpy_names)
                or (isinstance(func, ast.Name) and func.id in numpy_load_names)
            )
            kw = {k.arg: k.value for k in node.keywords if k.arg is not None}
            if is_np_load and not (
                isinstance(kw.get("allow_pickle"), ast.Constant) and kw["allow_pickle"].value is False
            ):
                flag(node, "numpy.load without allow_pickle=False")
            ap = kw.get("allow_pickle")
            if ap is not None and not (isinstance(ap, ast.Constant) and ap.value is False):
                flag(node, "allow_pickle other than False")
    return found


def _sources() -> list[Path]:
    return sorted(p for pkg in SCANNED_PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def test_nothing_is_ever_unpickled_or_evaluated() -> None:
    files = _sources()
    assert len(files) >= 20 and {f.relative_to(ROOT).parts[0] for f in files} == set(SCANNED_PACKAGES)
    found = [hit for f in files for hit in scan_source(f.read_text(encoding="utf-8"), str(f.relative_to(ROOT)))]
    assert found == []


@pytest.mark.parametrize("bad", [
    "import pickle",
    "import pickle as p",
    "from pickle import loads",
    "import dill",
    "import shelve",
    "from marshal import loads",
    "eval('1+1')",
    "exec('x = 1')",
    "import builtins\nbuiltins.eval('1')",
    "import numpy as np\nnp.load('x.npy')",
    "import numpy as np\nnp.load('x.npz', allow_pickle=True)",
    "import numpy\nnumpy.load('x.npy', mmap_mode='r')",
    "from numpy import load\nload('x.npy')",
    "from numpy import load as ld\nld('x.npy', allow_pickle=flag)",
    "import pandas as pd\npd.read_pickle('x')",
    "import numpy as np\nnp.lib.format.read_array(f, allow_pickle=True)",
])
def test_scanner_flags_unsafe_code(bad: str) -> None:
    assert scan_source(bad) != []


def test_scanner_accepts_safe_code() -> None:
    safe = (
        "import json, ast\nimport numpy as np\n"
        "with np.load(path, allow_pickle=False) as z:\n    pass\n"
        "json.loads(text)\nast.literal_eval('1')\nmodel.eval()\nself.load(x)\nnp.loadtxt(p)\n"
        "np.savez(p, a=a)\n"
    )
    assert scan_source(safe) == []


# --------------------------------------------------------------------------- static: loopback listeners
def is_loopback_endpoint(ep: str) -> bool:
    """Whether a Zenoh locator ``proto/host:port`` names a loopback host."""
    host = ep.split("/", 1)[1].rsplit(":", 1)[0].strip("[]")
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def test_default_endpoint_is_loopback() -> None:
    assert DEFAULT_ENDPOINT.startswith("tcp/") and is_loopback_endpoint(DEFAULT_ENDPOINT)
    assert not is_loopback_endpoint("tcp/0.0.0.0:7447") and not is_loopback_endpoint("tcp/[::]:7447")


def test_connection_flags_default_to_loopback_or_nothing() -> None:
    p = argparse.ArgumentParser()
    add_connection_flags(p)
    s = settings_from_args(p.parse_args([]))
    assert s.listen == () and s.connect == () and s.multicast_scouting is False
    conf = s.to_config()  # listen nowhere: NOT Zenoh's peer default tcp/[::]:0
    assert json.loads(conf.get_json("listen/endpoints")) == []
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False

    p = argparse.ArgumentParser()
    add_connection_flags(p, default_listen=(DEFAULT_ENDPOINT,))
    s = settings_from_args(p.parse_args([]))
    assert s.listen == (DEFAULT_ENDPOINT,)
    assert json.loads(s.to_config().get_json("listen/endpoints")) == [DEFAULT_ENDPOINT]


def test_every_cli_command_defaults_to_loopback() -> None:
    from streamid.commands.main import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    with_flags = {}
    for name, cmd in sub.choices.items():
        listen = cmd.get_default("_zenoh_default_listen")
        connect = cmd.get_default("_zenoh_default_connect")
        if listen is None and connect is None:
            continue  # no Zenoh connection flags
        with_flags[name] = (tuple(listen), tuple(connect))
        for ep in (*listen, *connect):
            assert is_loopback_endpoint(ep), f"streamid {name}: default endpoint {ep} is not loopback"
    assert with_flags.get("daemon", ((), ()))[0] == (DEFAULT_ENDPOINT,)
    daemon_settings = settings_from_args(parser.parse_args(["daemon"]))
    assert daemon_settings.listen == (DEFAULT_ENDPOINT,) and daemon_settings.multicast_scouting is False


def test_viz_server_binds_loopback_by_default() -> None:
    from streamid.viz.rerun_view import VizSettings

    assert ipaddress.ip_address(VizSettings().serve_bind).is_loopback


def test_no_source_binds_every_interface() -> None:
    """No string constant (outside docstrings) is a bind-all address."""
    bind_all = ("0.0.0.0", "::", "[::]")
    hits = []
    for f in _sources():
        tree = ast.parse(f.read_text(encoding="utf-8"))
        docstrings = {
            id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
        }
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                v = node.value
                if v in bind_all or any(f"/{a}:" in v for a in bind_all):
                    hits.append(f"{f.relative_to(ROOT)}:{node.lineno}: {v!r}")
    assert hits == []
