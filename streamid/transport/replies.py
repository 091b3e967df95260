"""What a query keeps of its replies: :class:`Replies` and the bounds of :meth:`~streamid.transport.Bus.get`."""

from __future__ import annotations

__all__ = ["GET_MAX_BYTES", "GET_MAX_REPLIES", "GET_QUEUE", "Replies"]

#: What one :meth:`~streamid.transport.Bus.get` keeps unless its caller says less: replies, and their payload
#: bytes together.  Every reply beyond is measured (its length, never copied out of Zenoh) and counted in
#: :attr:`Replies.dropped`.
GET_MAX_REPLIES = 1024
GET_MAX_BYTES = 64 * 1024 * 1024
#: Replies Zenoh holds for a get before they are taken (each is taken, measured, copied or dropped at once):
#: what a flood of large replies can pile up in this process is this many messages, not the flood.
GET_QUEUE = 4


class Replies(list[tuple[str, bytes]]):
    """The ``(key, payload)`` replies a get kept, with what it dropped beyond its bounds."""

    def __init__(self) -> None:
        super().__init__()
        #: Replies not kept: beyond the reply or byte bound, or one larger than the bound of one reply.
        self.dropped = 0
        #: Their payload bytes (measured, not read).
        self.dropped_bytes = 0
