"""A forger in its own process (so a test's RSS figure is the asker's): answers queries with a flood of large replies.

``python tests/reply_flood_peer.py ENDPOINT KEY COUNT PAYLOAD_FILE``: a client session on ``ENDPOINT`` declares a
queryable on ``KEY`` that answers every query with ``COUNT`` replies, each the bytes of ``PAYLOAD_FILE`` (the same
object every time: the flood costs this process one payload, not ``COUNT``).  Prints ``ready`` once declared and
serves until standard input closes (at most 10 min).
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

from streamid.transport import Bus, ZenohSettings


def main() -> None:
    ep, key, count, payload_file = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
    payload = Path(payload_file).read_bytes()
    with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as bus:
        bus.queryable(key, lambda _k: [payload] * count)
        print("ready", flush=True)
        done = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
        done.wait(600)


if __name__ == "__main__":
    main()
