"""The package's public names: ``streamid.__all__`` resolves, lazily, and agrees with its typing view."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

import streamid

INIT = Path(streamid.__file__)


def _module_exists(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False


@pytest.mark.parametrize("name", streamid.__all__)
def test_every_exported_name_resolves(name: str) -> None:
    module = streamid._EXPORTS.get(name)
    if name == "OnlineIdentifier" and not _module_exists("streamid.online.identifier"):
        pytest.skip("streamid.online.identifier does not exist yet (the online rewrite adds it)")
    value = getattr(streamid, name)
    assert value is not None
    if module is not None:
        assert value is getattr(importlib.import_module(module), name)
        exec(f"from streamid import {name}", {})  # the from-import form works too


def test_all_lists_every_export_once_and_dir_shows_them() -> None:
    assert len(streamid.__all__) == len(set(streamid.__all__))
    assert set(streamid.__all__) == {"StreamidError", "__version__", *streamid._EXPORTS}
    assert dir(streamid) == sorted(streamid.__all__)  # the public names, none of the module's own imports


def test_the_type_checking_imports_are_the_lazy_exports() -> None:
    """What IDEs and mypy see (the ``if TYPE_CHECKING:`` imports) is what ``__getattr__`` returns."""
    tree = ast.parse(INIT.read_text(encoding="utf-8"))
    block = next(
        n for n in tree.body if isinstance(n, ast.If) and isinstance(n.test, ast.Name) and n.test.id == "TYPE_CHECKING"
    )
    seen = {
        alias.name: node.module
        for node in block.body
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert seen == streamid._EXPORTS


def test_an_unknown_name_is_an_attribute_error_and_submodules_still_import() -> None:
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = streamid.nope
    from streamid import logs

    assert logs.__name__ == "streamid.logs"


def test_import_streamid_stays_light() -> None:
    code = (
        "import sys, streamid; "
        "print(' '.join(m for m in ('numpy', 'scipy', 'zenoh', 'rerun', 'mcap') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "", f"import streamid loaded {out.stdout.strip()}"
