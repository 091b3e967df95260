"""The packages' public names: ``streamid``'s, ``streamid.online``'s and ``streamid.engine``'s ``__all__``
resolve, lazily, and agree with their typing view; the ``streamid`` command's parser loads no numerics."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import streamid
import streamid.engine
import streamid.online

#: the packages whose names are imported on first use, and the names each has that are not lazy exports
LAZY = [(streamid, {"StreamidError", "__version__"}), (streamid.online, set()), (streamid.engine, set())]


@pytest.mark.parametrize(("package", "name"), [(p, n) for p, _ in LAZY for n in p.__all__],
                         ids=lambda v: getattr(v, "__name__", v))
def test_every_exported_name_resolves(package: Any, name: str) -> None:
    module = package._EXPORTS.get(name)
    value = getattr(package, name)
    assert value is not None
    if module is not None:
        assert value is getattr(importlib.import_module(module), name)
        exec(f"from {package.__name__} import {name}", {})  # the from-import form works too


@pytest.mark.parametrize(("package", "own"), LAZY, ids=lambda v: getattr(v, "__name__", ""))
def test_all_lists_every_export_once_and_dir_shows_them(package: Any, own: set[str]) -> None:
    assert len(package.__all__) == len(set(package.__all__))
    assert set(package.__all__) == {*own, *package._EXPORTS}
    assert dir(package) == sorted(package.__all__)  # the public names, none of the module's own imports


@pytest.mark.parametrize("package", [p for p, _ in LAZY], ids=lambda p: p.__name__)
def test_the_type_checking_imports_are_the_lazy_exports(package: Any) -> None:
    """What IDEs and mypy see (the ``if TYPE_CHECKING:`` imports) is what ``__getattr__`` returns."""
    tree = ast.parse(Path(package.__file__).read_text(encoding="utf-8"))
    block = next(
        n for n in tree.body if isinstance(n, ast.If) and isinstance(n.test, ast.Name) and n.test.id == "TYPE_CHECKING"
    )
    seen = {
        alias.name: node.module
        for node in block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert seen == package._EXPORTS


def test_an_unknown_name_is_an_attribute_error_and_submodules_still_import() -> None:
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = streamid.nope
    with pytest.raises(AttributeError, match="module 'streamid.online' has no attribute 'nope'"):
        _ = streamid.online.nope
    from streamid import logs

    assert logs.__name__ == "streamid.logs"


def test_import_streamid_stays_light() -> None:
    code = (
        "import sys, streamid; "
        "print(' '.join(m for m in ('numpy', 'scipy', 'zenoh', 'rerun', 'mcap') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "", f"import streamid loaded {out.stdout.strip()}"


def test_the_daemons_state_store_imports_without_the_engine() -> None:
    """``streamid.online``'s names are lazy too: its light modules (the snapshot the state store reads and writes)
    do not pull in the identifier, the engine, numpy or scipy (0.9 s of imports before)."""
    code = (
        "import sys, streamid.daemon.state_store; "
        "print(' '.join(m for m in ('streamid.online.identifier', 'streamid.engine', 'numpy', 'scipy') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "", f"the state store loaded {out.stdout.strip()}"


def test_the_command_line_parser_loads_no_engine_and_no_scipy() -> None:
    """``streamid --help`` builds every command's parser (the entry points' too): none may import the engine's
    solver, numba or scipy at module level (1.9 s before, 0.45 s now); a command pays for them when it runs.
    Nor the lab's file readers (asammdf brings pandas; rosbags, h5py): only a command reading such a file does."""
    heavy = ("streamid.engine.search.coevolution", "numba", "scipy", "asammdf", "pandas", "rosbags", "h5py",
             "streamid.logs.mdf_file", "streamid.logs.ros2_bag", "streamid.logs.mat73_file")
    code = (
        "import sys; from streamid.commands.main import build_parser; build_parser(); "
        f"print(' '.join(m for m in {heavy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "", f"the parser loaded {out.stdout.strip()}"
