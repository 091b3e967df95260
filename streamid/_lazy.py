"""Names a package exports, imported on first use (PEP 562), so that importing the package stays light.

``streamid`` and ``streamid.online`` use it: ``import streamid`` needs no numpy, and a module such as
``streamid.online.snapshot`` (the state store's) can be imported without the identifier and the engine
(0.9 s before this).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, str], namespace: dict[str, Any],
                 public: list[str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package``, whose name ``N`` lives in module ``exports[N]``.

    ``namespace`` is the package's ``globals()``: a name, once imported, is kept there (later lookups do not
    reach ``__getattr__``). ``public`` is its ``__all__``.
    """

    def __getattr__(name: str) -> object:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        try:
            value = getattr(importlib.import_module(module), name)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            raise AttributeError(f"{package}.{name} lives in {module}, which this installation does not have") from exc
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(public)

    return __getattr__, __dir__
