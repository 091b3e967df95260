"""The installed distribution's version (a module of its own, so that the packages that stamp it on what they write
need not import the package root, which names every layer)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

__all__ = ["__version__"]

try:
    __version__ = version("streamid")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+local"
