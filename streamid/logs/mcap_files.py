"""MCAP logs of Zenoh traffic: the only module of streamid that imports ``mcap``.

A streamid log is an MCAP file with one channel per Zenoh key (topic = key).
Sample-batch keys (``streamid/<s>/samples|u|y``) use the protobuf schema
``streamid.SampleBatch`` (schema encoding ``protobuf`` = serialized
``FileDescriptorSet``, message encoding ``protobuf``), so any MCAP tool decodes
them; ``model``/``status`` keys are schemaless ``json``; anything else is
recorded as schemaless raw bytes.  Each message's data is the exact Zenoh
payload; ``log_time`` is the receive time (ns since the Unix epoch, or the
sample clock for generated logs) and ``publish_time`` the batch's ``t0_ns``.

Reading walks the file record by record: a truncated or corrupt file raises a
:class:`~streamid.errors.LogError` naming the file and byte position, and
``partial=True`` instead yields every complete, valid chunk and reports the
problem in :attr:`LogReader.problem`.  A chunk is decompressed here, never beyond
:data:`MAX_CHUNK_BYTES`: one that declares more (its ``uncompressed_size``) is refused
before anything is allocated, one that expands beyond what it declares is refused as
soon as it does.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import time
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

from mcap.records import Channel as _McapChannel
from mcap.records import Chunk as _McapChunk
from mcap.records import Message as _McapMessage
from mcap.records import Metadata as _McapMetadata
from mcap.records import Schema as _McapSchema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from streamid.wire import codec
from streamid.errors import CodecError, ConfigError, LogError
from streamid.wire.keys import DOCUMENT_KINDS, SAMPLE_KINDS, parse_key

__all__ = [
    "LOG_FORMAT",
    "MAX_CHUNK_BYTES",
    "LogMessage",
    "LogWriter",
    "LogReader",
    "LogInfo",
    "iter_log",
    "log_info",
]

_log = logging.getLogger(__name__)

LOG_FORMAT = "streamid.log/1"
MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_METADATA = 0x0C
_OP_NAMES = {
    0x01: "header", 0x02: "footer", 0x03: "schema", 0x04: "channel", 0x05: "message",
    0x06: "chunk", 0x07: "message index", 0x08: "chunk index", 0x09: "attachment",
    0x0A: "attachment index", 0x0B: "statistics", 0x0C: "metadata", 0x0D: "metadata index",
    0x0E: "summary offset", 0x0F: "data end",
}
_PARSED_OPS = {_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_METADATA}
# A footer record plus closing magic appended to one record so that mcap's
# StreamReader parses exactly that record and stops cleanly.
_SENTINEL = struct.pack("<BQ", _OP_FOOTER, 20) + b"\x00" * 20 + MAGIC
_MAX_RECORD = 1 << 31  # refuse records larger than 2 GiB (corrupt length fields)
#: Most bytes one chunk is decompressed to (streamid writes chunks of ~1 MiB; mcap's default is 1 MiB).
MAX_CHUNK_BYTES = 256 * 1024 * 1024


class LogMessage(NamedTuple):
    """One logged Zenoh sample: key, receive time (ns) and the exact payload bytes."""

    key: str
    log_time_ns: int
    data: bytes


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------
class LogWriter:
    """Write Zenoh traffic to a chunked, zstd-compressed MCAP file.

    Parameters
    ----------
    path : str or Path
        File to create (overwritten).
    chunk_bytes : int
        Close a chunk once it holds this many uncompressed bytes.
    chunk_interval_s : float
        Close a chunk at the latest this long after its first message (checked
        on :meth:`write` and :meth:`maybe_flush`), so that a killed writer
        loses at most that much data.
    metadata : mapping of str to str, optional
        Written as an MCAP metadata record named ``streamid``.
    compression : {"zstd", "lz4", "none"}
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        chunk_bytes: int = 1 << 20,
        chunk_interval_s: float = 1.0,
        metadata: Mapping[str, str] | None = None,
        compression: str = "zstd",
    ) -> None:
        if chunk_bytes < 1:
            raise ConfigError(f"chunk_bytes must be >= 1; got {chunk_bytes!r}")
        if not chunk_interval_s > 0:
            raise ConfigError(f"chunk_interval_s must be > 0 seconds; got {chunk_interval_s!r}")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}.get(compression)
        if comp is None:
            raise ConfigError(f"compression must be one of zstd, lz4, none; got {compression!r}")
        self.path = Path(path)
        try:
            self._file = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise LogError(f"cannot create log file {str(self.path)!r}: {exc}") from exc
        self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=comp)
        self._writer.start(profile="", library=f"streamid {_version()}")
        meta = {"format": LOG_FORMAT}
        meta.update({str(k): str(v) for k, v in (metadata or {}).items()})
        self._writer.add_metadata("streamid", meta)
        self._schema_id: int | None = None
        self._channels: dict[str, int] = {}
        self._interval = float(chunk_interval_s)
        self._chunk_started: float | None = None
        self._pending = 0
        self.messages = 0
        self.bytes = 0
        self._closed = False

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _channel_id(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is not None:
            return cid
        try:
            kind = parse_key(key)[1]
        except ConfigError:
            kind = ""
        if kind in SAMPLE_KINDS:
            if self._schema_id is None:
                self._schema_id = self._writer.register_schema(
                    codec.SCHEMA_NAME, codec.SCHEMA_ENCODING, codec.FILE_DESCRIPTOR_SET
                )
            cid = self._writer.register_channel(key, codec.MESSAGE_ENCODING, self._schema_id)
        elif kind in DOCUMENT_KINDS:
            cid = self._writer.register_channel(key, "json", 0)
        else:
            cid = self._writer.register_channel(key, "", 0)
        self._channels[key] = cid
        return cid

    def write(
        self,
        key: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
        sequence: int | None = None,
    ) -> None:
        """Append one message.

        ``publish_time_ns`` and ``sequence`` default to the batch's ``t0_ns``
        and ``seq`` for sample batches, else to ``log_time_ns`` and 0.
        """
        if self._closed:
            raise LogError(f"log {str(self.path)!r} is closed; cannot write key {key!r}")
        seq = sequence or 0
        if publish_time_ns is None:
            head = codec.peek_header(data)
            if head is not None:
                seq, publish_time_ns = head
            else:
                publish_time_ns = log_time_ns
        now = time.monotonic()
        if self._chunk_started is None:
            self._chunk_started = now
        self._writer.add_message(
            self._channel_id(key), log_time=int(log_time_ns), data=data,
            publish_time=int(publish_time_ns), sequence=seq & 0xFFFFFFFF,
        )
        self.messages += 1
        self.bytes += len(data)
        self._pending += 1
        if now - self._chunk_started >= self._interval:
            self.flush()

    def maybe_flush(self) -> bool:
        """Close the open chunk if its first message is older than the interval."""
        if self._chunk_started is not None and time.monotonic() - self._chunk_started >= self._interval:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        """Close the open chunk (if any) and flush it to the file."""
        if self._closed:
            return
        self._writer.flush()
        self._chunk_started = None
        self._pending = 0

    def close(self) -> None:
        """Finish the file (summary, indexes, footer) and close it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()


def _version() -> str:
    from streamid._version import __version__

    return __version__


# ---------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------
def _parse_record(raw: bytes) -> list[Any]:
    """Parse one complete MCAP record (a chunk expands into its records)."""
    reader = StreamReader(io.BytesIO(raw + _SENTINEL), skip_magic=True, validate_crcs=True,
                          record_size_limit=_MAX_RECORD)
    return [r for r in reader.records if not isinstance(r, _McapChunk)]


def _inflate(compression: str, data: bytes, most: int) -> bytes:
    """``data`` decompressed, at most ``most`` bytes of it (a longer result is cut there: the caller compares)."""
    if compression == "zstd":
        import zstandard

        parts: list[bytes] = []
        got = 0
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as reader:
            while got < most:
                piece = reader.read(min(1 << 20, most - got))
                if not piece:
                    break
                parts.append(piece)
                got += len(piece)
        return b"".join(parts)
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-untyped]

        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=most))
    raise ValueError(f"unknown chunk compression {compression!r}; accepted: zstd, lz4, none")


def _unpacked_chunk(raw: bytes) -> tuple[int, bytes | None]:
    """(the uncompressed size a chunk record declares, the same record uncompressed within
    :data:`MAX_CHUNK_BYTES`, or None when it declares more).  ValueError if it expands to other than it declares."""
    start, end, size, crc, n = struct.unpack_from("<QQQII", raw, 9)
    compression = raw[9 + 32: 9 + 32 + n].decode("utf-8", "replace")
    if size > MAX_CHUNK_BYTES:
        return size, None
    if compression == "":
        return size, raw
    (n_data,) = struct.unpack_from("<Q", raw, 9 + 32 + n)
    data = raw[9 + 40 + n: 9 + 40 + n + n_data]
    out = _inflate(compression, data, size + 1)
    if len(out) != size:
        more = "more" if len(out) > size else "fewer"
        raise ValueError(f"its {compression} data expands to {more} than the {size} bytes it declares")
    body = struct.pack("<QQQII", start, end, size, crc, 0) + struct.pack("<Q", size) + out
    return size, struct.pack("<BQ", _OP_CHUNK, len(body)) + body


class LogReader:
    """Iterate the messages of an MCAP log as :class:`LogMessage` in file order.

    Parameters
    ----------
    path : str or Path
    keys : collection of str, optional
        Only yield messages of these keys (topics).
    partial : bool
        ``False`` (default): a truncated or corrupt file raises
        :class:`LogError` naming the file and byte position, before anything
        is yielded when the damage is in the record framing.  ``True``: yield
        every complete and valid chunk, skip damaged ones, stop at a
        truncation, and describe what was skipped in :attr:`problem`.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        keys: Collection[str] | None = None,
        partial: bool = False,
    ) -> None:
        self.path = Path(path)
        self.keys = frozenset(keys) if keys is not None else None
        self.partial = partial
        #: Description of the damage found (``partial=True``), else ``None``.
        self.problem: str | None = None
        #: Metadata records read so far (name -> dict).
        self.metadata: dict[str, dict[str, str]] = {}
        #: Byte offset up to which the file was read cleanly.
        self.good_bytes = 0
        if not self.path.is_file():
            raise LogError(f"log file must be an existing MCAP file; got {str(self.path)!r}")

    def _fail(self, msg: str) -> None:
        text = f"{self.path}: {msg}"
        if not self.partial:
            raise LogError(
                text + " (its complete chunks are played by `streamid replay --partial`, read by LogReader(partial=True))"
            )
        if self.problem is None:
            self.problem = text
        else:
            self.problem += "; " + msg
        _log.warning("%s", text)

    def _frames(self, f: io.BufferedReader, size: int) -> Iterator[tuple[int, int, int]]:
        """Yield ``(position, opcode, length)`` of every complete record; report damage."""
        head = f.read(8)
        if head != MAGIC:
            self._fail(f"not an MCAP file: byte 0 must start with the MCAP magic {MAGIC!r}; "
                       f"got {head!r}")
            return
        pos = 8
        while True:
            f.seek(pos)
            hdr = f.read(9)
            if len(hdr) < 9:
                self._fail(f"truncated at byte {pos} of {size}: the file ends without an MCAP "
                           f"footer (was the writer killed?)")
                return
            opcode, length = struct.unpack("<BQ", hdr)
            if length > _MAX_RECORD or pos + 9 + length > size:
                name = _OP_NAMES.get(opcode, f"opcode 0x{opcode:02x}")
                self._fail(f"truncated at byte {pos} of {size}: the {name} record there declares "
                           f"{length} bytes but only {size - pos - 9} remain")
                return
            yield pos, opcode, length
            pos += 9 + length
            if opcode == _OP_FOOTER:
                f.seek(pos)
                if f.read(8) != MAGIC:
                    self._fail(f"corrupt end at byte {pos}: the footer must be followed by the "
                               f"MCAP magic")
                return

    def _check_framing(self) -> None:
        with open(self.path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            for _ in self._frames(f, size):
                pass

    def __iter__(self) -> Iterator[LogMessage]:
        if not self.partial:
            self._check_framing()  # fail before yielding anything on truncation
        channels: dict[int, str] = {}
        schemas: set[int] = set()
        with open(self.path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            for pos, opcode, length in self._frames(f, size):
                if opcode not in _PARSED_OPS:
                    self.good_bytes = pos + 9 + length
                    continue
                f.seek(pos)
                raw = f.read(9 + length)
                try:
                    if opcode == _OP_CHUNK:
                        size, unpacked = _unpacked_chunk(raw)
                        if unpacked is None:
                            self._fail(f"chunk record at byte {pos} declares {size} uncompressed bytes; a chunk is "
                                       f"read up to {MAX_CHUNK_BYTES} bytes (MAX_CHUNK_BYTES)"
                                       + ("; skipped" if self.partial else ""))
                            continue
                        raw = unpacked
                    records = _parse_record(raw)
                except LogError:  # said by _fail above
                    raise
                except Exception as exc:  # noqa: BLE001 - any parser failure is damage
                    name = _OP_NAMES.get(opcode, f"opcode 0x{opcode:02x}")
                    self._fail(f"corrupt {name} record at byte {pos} ({type(exc).__name__}: "
                               f"{exc})" + ("; skipped" if self.partial else ""))
                    continue
                self.good_bytes = pos + 9 + length
                for rec in records:
                    if isinstance(rec, _McapMessage):
                        key = channels.get(rec.channel_id)
                        if key is None:
                            self._fail(f"message at byte {pos} refers to unknown channel "
                                       f"{rec.channel_id}")
                            continue
                        if self.keys is None or key in self.keys:
                            yield LogMessage(key, rec.log_time, rec.data)
                    elif isinstance(rec, _McapChannel):
                        channels[rec.id] = rec.topic
                    elif isinstance(rec, _McapSchema):
                        schemas.add(rec.id)
                    elif isinstance(rec, _McapMetadata):
                        self.metadata[rec.name] = dict(rec.metadata)


def iter_log(
    path: str | os.PathLike[str],
    *,
    keys: Collection[str] | None = None,
    partial: bool = False,
) -> Iterator[LogMessage]:
    """Shortcut for ``iter(LogReader(path, keys=keys, partial=partial))``."""
    return iter(LogReader(path, keys=keys, partial=partial))


@dataclass(frozen=True)
class LogInfo:
    """Summary of a log: per-key message counts and sample counts, time span."""

    path: Path
    messages: dict[str, int]
    samples: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    metadata: dict[str, dict[str, str]]
    problem: str | None

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def streams(self) -> list[str]:
        """Stream names carrying sample batches."""
        out = []
        for key in self.messages:
            try:
                stream, kind = parse_key(key)
            except ConfigError:
                continue
            if kind in SAMPLE_KINDS and stream not in out:
                out.append(stream)
        return out


def log_info(path: str | os.PathLike[str], *, partial: bool = False) -> LogInfo:
    """Read a whole log and summarise it (see :class:`LogInfo`)."""
    reader = LogReader(path, partial=partial)
    messages: dict[str, int] = {}
    samples: dict[str, int] = {}
    start = end = None
    for key, t, data in reader:
        messages[key] = messages.get(key, 0) + 1
        start = t if start is None else min(start, t)
        end = t if end is None else max(end, t)
        try:
            n = len(codec.decode(data))
        except CodecError:
            continue
        samples[key] = samples.get(key, 0) + n
    return LogInfo(Path(path), messages, samples, start, end, reader.metadata, reader.problem)
