"""One exception hierarchy for everything streamid raises on purpose.

Every message states the rule that was broken, the accepted form and the
offending value, so that a user can fix the input without reading the code.
"""

from __future__ import annotations

__all__ = [
    "StreamidError",
    "ConfigError",
    "DataError",
    "CodecError",
    "LogError",
    "TransportError",
    "NoDaemonError",
    "NoModelYetError",
    "ModelFormatError",
]


class StreamidError(Exception):
    """Base class of every error streamid raises deliberately."""


class ConfigError(StreamidError, ValueError):
    """A configuration value (file, flag or argument) is out of its accepted form."""


class DataError(StreamidError, ValueError):
    """Input data cannot be identified as given (NaN, zero range, too short, unknown column)."""


class CodecError(StreamidError, ValueError):
    """A wire-format payload cannot be decoded."""


class LogError(StreamidError):
    """An MCAP log cannot be read or written (names the file and position)."""


class TransportError(StreamidError):
    """The Zenoh transport could not be opened or used."""


class NoDaemonError(TransportError):
    """Nothing reachable at the endpoint: no daemon, router or peer answered (names the endpoint)."""


class NoModelYetError(StreamidError, LookupError):
    """The network is reachable but no model of the stream was published yet (names the stream)."""


class ModelFormatError(StreamidError, ValueError):
    """A model or state file is not a valid streamid document."""
