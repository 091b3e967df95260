"""The architecture rules, checked on the source: every import of every module is read with ``ast``.

Scanned: every ``.py`` file under ``streamid/``, ``recorders/``, ``replay/`` and ``benchmarks/``.  An import is any
``import x`` / ``from x import y`` anywhere in the file (module level, inside functions, under
``if TYPE_CHECKING:``), relative imports resolved against the importing module, plus
``importlib.import_module("literal")``.  ``from pkg import name`` counts as importing ``pkg.name``
when that is one of the scanned modules.

======================  ==========================================================================
rule                    what it says
======================  ==========================================================================
zenoh-adapter           ``zenoh`` is imported by exactly one module: streamid/transport/zenoh_bus.py
rerun-adapter           ``rerun`` (and ``rerun.*``, ``rerun_bindings``) by exactly one module:
                        streamid/viz/rerun_view.py
mcap-adapter            ``mcap`` (and ``mcap.*``, ``mcap_protobuf``) by exactly one module:
                        streamid/logs/mcap_files.py
asammdf-adapter         ``asammdf`` by exactly one module: streamid/logs/mdf_file.py (MDF files)
rosbags-adapter         ``rosbags`` by exactly one module: streamid/logs/ros2_bag.py (ROS 2 bags, CDR)
h5py-adapter            ``h5py`` by exactly one module: streamid/logs/mat73_file.py (MATLAB v7.3)
engine-is-numerics      streamid/engine/ imports only the stdlib, numpy, scipy, threadpoolctl, numba,
                        streamid.errors, streamid._lazy, streamid.bounded_files (stdlib only: a file
                        read under a bound, which Model.load and the daemon's state store share) and
                        streamid.engine.* (so never online, daemon, wire, logs, viz, transport,
                        commands, bench, zenoh, rerun, mcap)
sim-is-numerics         streamid/sim/ imports only the stdlib, numpy, scipy, streamid.errors,
                        streamid.sim.* and streamid.engine.*
wire-stands-alone       streamid/wire/ imports only the stdlib, numpy, streamid.errors and
                        streamid.wire.*
online-core             streamid/online/ imports of streamid are only streamid.online.*,
                        streamid.engine.*, streamid.wire.*, streamid.errors and streamid._lazy
                        (never transport, daemon, viz, logs, commands, sim)
product-not-tooling     no module of streamid/ imports recorders, replay or benchmarks (they are
                        reached through entry points)
benchmarks-apart        no product package (streamid/, recorders/, replay/) imports benchmarks/:
                        the benchmarks are tooling beside the product, never inside it
recorders-not-replay    recorders/ never imports replay
replay-not-recorders    replay/ never imports recorders
module-size             no scanned file is longer than 550 lines (the aim is under 500)
======================  ==========================================================================

The data flow is one way, transport -> online -> engine -> publishers: engine-is-numerics keeps the
engine from importing online, online-core keeps online from importing the daemon.

Every broken rule is one line of the failure: ``path:line: importer imports target  [rule] reason``.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCANNED_PACKAGES = ("streamid", "recorders", "replay", "benchmarks")
MAX_LINES = 550

#: The third-party libraries that each have a single adapter module.
ADAPTERS = {
    "zenoh-adapter": (("zenoh",), "streamid.transport.zenoh_bus"),
    "rerun-adapter": (("rerun", "rerun_bindings"), "streamid.viz.rerun_view"),
    "mcap-adapter": (("mcap", "mcap_protobuf"), "streamid.logs.mcap_files"),
    "asammdf-adapter": (("asammdf",), "streamid.logs.mdf_file"),
    "rosbags-adapter": (("rosbags",), "streamid.logs.ros2_bag"),
    "h5py-adapter": (("h5py",), "streamid.logs.mat73_file"),
}


@dataclass(frozen=True)
class Import:
    """One import found in a scanned module."""

    importer: str  # dotted name of the importing module
    path: str  # its file, relative to the repository root
    line: int
    target: str  # the absolute dotted name imported


@dataclass(frozen=True)
class Source:
    """One scanned file."""

    module: str
    path: Path
    is_package: bool  # an __init__.py


def within(name: str, *prefixes: str) -> bool:
    """``name`` is one of ``prefixes`` or a submodule of one."""
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def is_stdlib(name: str) -> bool:
    top = name.split(".")[0]
    return top in sys.stdlib_module_names or top == "__future__"


def imports_of(source: str, module: str, *, is_package: bool, known: Callable[[str], bool], path: str = "") -> list[Import]:
    """Every import of ``source`` (the text of module ``module``), resolved to absolute names.

    ``known(name)`` says whether ``name`` is a scanned module (for ``from pkg import submodule``).
    """
    package = module if is_package else module.rpartition(".")[0]
    found: list[Import] = []

    def add(node: ast.AST, target: str) -> None:
        found.append(Import(module, path, getattr(node, "lineno", 0), target))

    for node in ast.walk(ast.parse(source, filename=path or module)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(node, alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                if node.level - 1 >= len(parts):
                    raise ValueError(f"{path or module}:{node.lineno}: relative import beyond the top-level package")
                base = ".".join(parts[: len(parts) - (node.level - 1)])
                origin = f"{base}.{node.module}" if node.module else base
            else:
                origin = node.module or ""
            add(node, origin)
            for alias in node.names:
                if alias.name != "*" and known(f"{origin}.{alias.name}"):
                    add(node, f"{origin}.{alias.name}")
        elif (
            isinstance(node, ast.Call)
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
            and (
                (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                or (isinstance(node.func, ast.Name) and node.func.id in ("import_module", "__import__"))
            )
        ):
            add(node, node.args[0].value)
    return found


@lru_cache(maxsize=1)
def sources() -> tuple[Source, ...]:
    found = []
    for pkg in SCANNED_PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            is_package = parts[-1] == "__init__"
            found.append(Source(".".join(parts[:-1] if is_package else parts), path, is_package))
    return tuple(found)


@lru_cache(maxsize=1)
def all_imports() -> tuple[Import, ...]:
    names = {s.module for s in sources()}
    found: list[Import] = []
    for s in sources():
        rel = str(s.path.relative_to(ROOT))
        found += imports_of(s.path.read_text(encoding="utf-8"), s.module, is_package=s.is_package, known=names.__contains__, path=rel)
    return tuple(found)


# --- the rules: each takes an import and returns why it breaks the rule, or None -------------------


def _adapter_rule(families: tuple[str, ...], owner: str) -> Callable[[Import], str | None]:
    def check(imp: Import) -> str | None:
        if within(imp.target, *families) and imp.importer != owner:
            return f"only {owner} may import {'/'.join(families)}: go through that adapter"
        return None

    return check


def _allow_only(scope: str, third_party: tuple[str, ...], internal: tuple[str, ...]) -> Callable[[Import], str | None]:
    def check(imp: Import) -> str | None:
        if not within(imp.importer, scope) or is_stdlib(imp.target):
            return None
        if within(imp.target, *third_party) or within(imp.target, *internal):
            return None
        allowed = ", ".join(("the stdlib",) + third_party + internal)
        return f"{scope} may import only {allowed}"

    return check


def _online(imp: Import) -> str | None:
    allowed = ("streamid.online", "streamid.engine", "streamid.wire", "streamid.errors", "streamid._lazy")
    if within(imp.importer, "streamid.online") and within(imp.target, "streamid") and not within(imp.target, *allowed):
        return ("streamid.online may import only streamid.online, streamid.engine, streamid.wire, streamid.errors "
                "and streamid._lazy of streamid")
    return None


def _product_not_tooling(imp: Import) -> str | None:
    if within(imp.importer, "streamid") and within(imp.target, "recorders", "replay", "benchmarks"):
        return "streamid never imports recorders, replay or benchmarks (use an entry point)"
    return None


def _benchmarks_apart(imp: Import) -> str | None:
    if within(imp.importer, "streamid", "recorders", "replay") and within(imp.target, "benchmarks"):
        return "no product package imports benchmarks (benchmarks drive the product, never the reverse)"
    return None


def _recorders_not_replay(imp: Import) -> str | None:
    if within(imp.importer, "recorders") and within(imp.target, "replay"):
        return "recorders never imports replay"
    return None


def _replay_not_recorders(imp: Import) -> str | None:
    if within(imp.importer, "replay") and within(imp.target, "recorders"):
        return "replay never imports recorders"
    return None


RULES: dict[str, Callable[[Import], str | None]] = {
    **{name: _adapter_rule(families, owner) for name, (families, owner) in ADAPTERS.items()},
    "engine-is-numerics": _allow_only(
        "streamid.engine", ("numpy", "scipy", "threadpoolctl", "numba"),
        ("streamid.errors", "streamid._lazy", "streamid.bounded_files", "streamid.engine"),
    ),
    "sim-is-numerics": _allow_only(
        "streamid.sim", ("numpy", "scipy"), ("streamid.errors", "streamid.sim", "streamid.engine")
    ),
    "wire-stands-alone": _allow_only("streamid.wire", ("numpy",), ("streamid.errors", "streamid.wire")),
    "online-core": _online,
    "product-not-tooling": _product_not_tooling,
    "benchmarks-apart": _benchmarks_apart,
    "recorders-not-replay": _recorders_not_replay,
    "replay-not-recorders": _replay_not_recorders,
}


def violations(rule: str, imports: Iterable[Import]) -> list[str]:
    check = RULES[rule]
    lines = []
    for imp in imports:
        why = check(imp)
        if why is not None:
            lines.append(f"{imp.path}:{imp.line}: {imp.importer} imports {imp.target}  [{rule}] {why}")
    return sorted(set(lines))


@pytest.mark.parametrize("rule", sorted(RULES))
def test_import_rule(rule: str) -> None:
    broken = violations(rule, all_imports())
    if broken:
        pytest.fail(f"{len(broken)} import(s) break the rule {rule!r}:\n" + "\n".join(broken), pytrace=False)


@pytest.mark.parametrize("rule", sorted(ADAPTERS))
def test_adapter_is_the_one_importer(rule: str) -> None:
    """The named adapter really imports its library (so "exactly one" holds, not "none")."""
    families, owner = ADAPTERS[rule]
    assert owner in {s.module for s in sources()}, f"the adapter module {owner} no longer exists: update {rule}"
    importers = {imp.importer for imp in all_imports() if within(imp.target, *families)}
    assert importers == {owner}, f"{'/'.join(families)} is imported by {sorted(importers)}; expected exactly {owner}"


def test_module_size() -> None:
    too_long = []
    for s in sources():
        n = len(s.path.read_text(encoding="utf-8").splitlines())
        if n > MAX_LINES:
            too_long.append(f"{s.path.relative_to(ROOT)}: {n} lines (limit {MAX_LINES}, aim under 500)  [module-size]")
    if too_long:
        pytest.fail(f"{len(too_long)} module(s) too long:\n" + "\n".join(too_long), pytrace=False)


# --- the scanner itself ------------------------------------------------------------------------------


def test_scanner_finds_every_kind_of_import() -> None:
    src = '''
from __future__ import annotations
from typing import TYPE_CHECKING
import zenoh.ext as zx
from . import sibling
from .sibling import thing
from .. import errors
from ..wire.codec import SampleBatch
if TYPE_CHECKING:
    from rerun.blueprint import Blueprint
def later():
    import mcap.writer
    import importlib
    return importlib.import_module("streamid.daemon.service")
'''
    known = {"streamid.engine.sibling", "streamid.errors"}.__contains__
    got = {i.target for i in imports_of(src, "streamid.engine.mod", is_package=False, known=known)}
    assert got == {
        "__future__",
        "typing",
        "zenoh.ext",
        "streamid.engine",
        "streamid.engine.sibling",
        "streamid",
        "streamid.errors",
        "streamid.wire.codec",
        "rerun.blueprint",
        "mcap.writer",
        "importlib",
        "streamid.daemon.service",
    }
    # In a package's __init__, one dot is the package itself.
    got = {i.target for i in imports_of("from .codec import x", "streamid.wire", is_package=True, known=known)}
    assert got == {"streamid.wire.codec"}


def test_rules_flag_what_they_must() -> None:
    def broken(importer: str, target: str) -> set[str]:
        imp = Import(importer, "x.py", 1, target)
        return {rule for rule, check in RULES.items() if check(imp) is not None}

    assert broken("streamid.engine.model", "streamid.online.window") == {"engine-is-numerics"}
    assert broken("streamid.engine.model", "rerun") == {"engine-is-numerics", "rerun-adapter"}
    assert broken("streamid.online.update", "streamid.daemon.config") == {"online-core"}
    assert broken("streamid.wire.documents", "streamid.engine.model") == {"wire-stands-alone"}
    assert broken("streamid.sim.piezo", "streamid.engine.model") == set()
    assert broken("streamid.commands.main", "replay.cli") == {"product-not-tooling"}
    assert broken("streamid.commands.main", "benchmarks.kit") == {"product-not-tooling", "benchmarks-apart"}
    assert broken("replay.player", "benchmarks.kit") == {"benchmarks-apart"}
    assert broken("benchmarks.command", "benchmarks.kit") == set()
    assert broken("replay.player", "recorders.devices") == {"replay-not-recorders"}
    assert broken("benchmarks.mr", "recorders.devices") == set()
    assert broken("recorders.cli", "replay.player") == {"recorders-not-replay"}
    assert broken("recorders.recorder", "mcap.writer") == {"mcap-adapter"}
    assert broken("streamid.transport.zenoh_bus", "zenoh") == set()
    assert broken("streamid.daemon.ros2", "rosbags.typesys") == {"rosbags-adapter"}
    assert broken("streamid.logs.datafile", "asammdf") == {"asammdf-adapter"}
    assert broken("streamid.logs.ros2_bag", "rosbags.highlevel") == set()
