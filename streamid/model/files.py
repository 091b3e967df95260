"""Reading a model file: bounded in size, UTF-8 (or UTF-16 with a BOM) JSON, a model-update document unwrapped."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from streamid.bounded_files import read_regular_file
from streamid.errors import ModelFormatError
from streamid.model.limits import MAX_MODEL_BYTES, parse_model_json

__all__ = ["read_model_file"]


def read_model_file(path: str | os.PathLike[str], formats: tuple[str, ...]) -> Any:
    """The parsed JSON document of the model file ``path`` (a ``streamid.model-update/1`` document's ``model``
    field when its own format is none of ``formats``); :class:`ModelFormatError` naming the file otherwise."""
    p = Path(path)
    try:
        raw = read_regular_file(p, MAX_MODEL_BYTES)  # UTF-8 (a BOM skipped), or UTF-16 with a BOM
        text = raw.decode("utf-16" if raw.startswith((b"\xff\xfe", b"\xfe\xff")) else "utf-8-sig")
    except ValueError as exc:  # not a regular file, or too large (UnicodeDecodeError is handled below)
        if isinstance(exc, UnicodeDecodeError):
            raise ModelFormatError(f"model file {str(p)!r} must be UTF-8 JSON text; {exc}") from None
        raise ModelFormatError(f"model file {str(p)!r}: {exc} (a model document is at most {MAX_MODEL_BYTES} "
                               "bytes, in a regular file)") from None
    except OSError as exc:
        raise ModelFormatError(f"model file must be a readable streamid.model/1 JSON file; cannot read {str(p)!r}: "
                               f"{exc}") from None
    d = parse_model_json(text, f"model file {str(p)!r}")
    if isinstance(d, Mapping) and d.get("format") not in formats and isinstance(d.get("model"), Mapping):
        d = d["model"]
    return d
