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
pyarrow-adapter         ``pyarrow`` (and ``pyarrow.*``) by exactly one module: streamid/logs/arrow_tables.py
model-stands-alone      streamid/model/ (the identified model) imports only the stdlib, numpy, numba,
                        streamid.errors, streamid._lazy, streamid.bounded_files, streamid.threads,
                        streamid.wire.names (stdlib only: the one rule for signal names, which the
                        model reader, the codec and the export share) and streamid.model.* (never
                        the engine, online, daemon, transport, ...)
asammdf-adapter         ``asammdf`` by exactly one module: streamid/logs/mdf_file.py (MDF files)
rosbags-adapter         ``rosbags`` by exactly one module: streamid/logs/ros2_bag.py (ROS 2 bags, CDR)
h5py-adapter            ``h5py`` by exactly one module: streamid/logs/mat73_file.py (MATLAB v7.3)
engine-is-numerics      streamid/engine/ imports only the stdlib, numpy, scipy, threadpoolctl, numba,
                        streamid.errors, streamid._lazy, streamid.threads, streamid.model.* and
                        streamid.engine.* (so never online, daemon, wire, logs, viz, transport,
                        commands, bench, zenoh, rerun, mcap)
sim-is-numerics         streamid/sim/ imports only the stdlib, numpy, scipy, streamid.errors and
                        streamid.sim.*
wire-stands-alone       streamid/wire/ imports only the stdlib, numpy, streamid.errors and
                        streamid.wire.*
online-core             streamid/online/ imports of streamid are only streamid.online.*,
                        streamid.model.*, streamid.engine.*, streamid.wire.*, streamid.errors and
                        streamid._lazy
                        (never transport, daemon, viz, logs, commands, sim)
product-not-tooling     no module of streamid/ imports recorders, replay or benchmarks (they are
                        reached through entry points)
benchmarks-apart        no product package (streamid/, recorders/, replay/) imports benchmarks/:
                        the benchmarks are tooling beside the product, never inside it
recorders-not-replay    recorders/ never imports replay
replay-not-recorders    replay/ never imports recorders
module-size             no scanned file is longer than 550 lines (the aim is under 500)
layers                  every import of one unit by another is listed in docs/architecture.md's table
                        (which names every unit and has no circle), and no module is on an import circle
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
    "pyarrow-adapter": (("pyarrow",), "streamid.logs.arrow_tables"),
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
    allowed = ("streamid.online", "streamid.model", "streamid.engine", "streamid.wire", "streamid.errors",
               "streamid._lazy")
    if within(imp.importer, "streamid.online") and within(imp.target, "streamid") and not within(imp.target, *allowed):
        return ("streamid.online may import only streamid.online, streamid.model, streamid.engine, streamid.wire, "
                "streamid.errors and streamid._lazy of streamid")
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
    "model-stands-alone": _allow_only(
        "streamid.model", ("numpy", "numba"),
        ("streamid.errors", "streamid._lazy", "streamid.bounded_files", "streamid.threads", "streamid.wire.names",
         "streamid.model"),
    ),
    "engine-is-numerics": _allow_only(
        "streamid.engine", ("numpy", "scipy", "threadpoolctl", "numba"),
        ("streamid.errors", "streamid._lazy", "streamid.threads", "streamid.model", "streamid.engine"),
    ),
    "sim-is-numerics": _allow_only("streamid.sim", ("numpy", "scipy"), ("streamid.errors", "streamid.sim")),
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

    assert broken("streamid.engine.identification", "streamid.online.window") == {"engine-is-numerics"}
    assert broken("streamid.engine.search.coevolution", "rerun") == {"engine-is-numerics", "rerun-adapter"}
    assert broken("streamid.model.narx", "streamid.engine.fit.rbf") == {"model-stands-alone"}
    assert broken("streamid.model.narx", "scipy.linalg") == {"model-stands-alone"}
    assert broken("streamid.engine.fit.rbf", "streamid.model.narx") == set()
    assert broken("streamid.online.update", "streamid.daemon.config") == {"online-core"}
    assert broken("streamid.online.update", "streamid.model.narx") == set()
    assert broken("streamid.wire.documents", "streamid.model.narx") == {"wire-stands-alone"}
    assert broken("streamid.sim.piezo", "streamid.engine.settings") == {"sim-is-numerics"}
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


# --- the layers: docs/architecture.md's table is the rule ------------------------------------------

ARCHITECTURE = ROOT / "docs" / "architecture.md"
TOOLING = ("recorders", "replay", "benchmarks")


def unit_of(module: str) -> str:
    """The unit ``module`` belongs to, named as in docs/architecture.md (without ``streamid.``): a package under
    streamid/, the engine's subpackages and top-level modules each their own, the top-level modules, the tooling."""
    parts = module.split(".")
    if parts[0] != "streamid":
        return parts[0]
    if len(parts) == 1:
        return "streamid"
    if parts[1] == "engine":
        return ".".join(parts[1:3])
    return parts[1]


def architecture_table(text: str) -> dict[str, set[str]]:
    """``unit -> the units it may import``, from the page's table (rows ``| `unit` | owns | `a`, `b` |``)."""
    table: dict[str, set[str]] = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`") and cells[0].endswith("`"):
            unit = cells[0].strip("`")
            if unit in table:
                raise AssertionError(f"docs/architecture.md names the unit {unit!r} twice")
            table[unit] = {n.strip().strip("`") for n in cells[2].split(",") if n.strip() not in ("", "—")}
    return table


def circle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of ``graph`` (a list of nodes, the first repeated at the end), or None: it is acyclic."""
    state: dict[str, int] = {}  # 1 on the path, 2 done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def unit_imports() -> dict[tuple[str, str], list[Import]]:
    names = {s.module for s in sources()}
    found: dict[tuple[str, str], list[Import]] = {}
    for imp in all_imports():
        if imp.target in names and unit_of(imp.importer) != unit_of(imp.target):
            found.setdefault((unit_of(imp.importer), unit_of(imp.target)), []).append(imp)
    return found


def test_the_architecture_page_names_every_unit_once_and_has_no_circle() -> None:
    table = architecture_table(ARCHITECTURE.read_text(encoding="utf-8"))
    units = {unit_of(s.module) for s in sources()}
    assert units - set(table) == set(), f"units missing from docs/architecture.md's table: {sorted(units - set(table))}"
    assert set(table) - units == set(), f"docs/architecture.md names units that do not exist: {sorted(set(table) - units)}"
    unknown = {f"{u} -> {t}" for u, ts in table.items() for t in ts if t not in table}
    assert not unknown, f"docs/architecture.md lets units import what it does not name: {sorted(unknown)}"
    product = {u: {t for t in ts if t not in TOOLING} for u, ts in table.items() if u not in TOOLING}
    assert circle(product) is None, f"docs/architecture.md's layers have a circle: {' -> '.join(circle(product) or [])}"


def test_every_import_between_units_is_allowed_by_the_architecture_page() -> None:
    table = architecture_table(ARCHITECTURE.read_text(encoding="utf-8"))
    broken = sorted(f"{imp.path}:{imp.line}: {imp.importer} imports {imp.target}  [layers] {a} may import only "
                    f"{', '.join(sorted(table.get(a, ()))) or 'nothing of the product'} (docs/architecture.md)"
                    for (a, b), imps in unit_imports().items() if b not in table.get(a, set()) for imp in imps)
    if broken:
        pytest.fail(f"{len(broken)} import(s) run against the layers:\n" + "\n".join(broken), pytrace=False)


def test_no_module_of_the_product_is_on_an_import_circle() -> None:
    names = {s.module for s in sources()}
    graph: dict[str, set[str]] = {}
    for imp in all_imports():
        if imp.target in names and imp.target != imp.importer and not within(imp.importer, *TOOLING):
            graph.setdefault(imp.importer, set()).add(imp.target)
    found = circle(graph)
    assert found is None, f"an import circle: {' -> '.join(found or [])}"


def test_the_layer_checks_catch_what_they_must() -> None:
    assert unit_of("streamid.engine.search.coevolution") == "engine.search"
    assert unit_of("streamid.engine.identification") == "engine.identification"
    assert unit_of("streamid.engine") == "engine" and unit_of("streamid.model.narx") == "model"
    assert unit_of("streamid") == "streamid" and unit_of("replay.player") == "replay"
    assert circle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert circle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    page = "| unit | owns | may import |\n| --- | --- | --- |\n| `model` | x | `errors`, `threads` |\n| `errors` | y | — |\n"
    assert architecture_table(page) == {"model": {"errors", "threads"}, "errors": set()}
    with pytest.raises(AssertionError, match="twice"):
        architecture_table(page + "| `model` | again | — |\n")
