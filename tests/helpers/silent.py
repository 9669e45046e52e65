"""A host that dials a TCP port and sends nothing until SIGTERM: what stops a Fast DDS TLS listener accepting
(strangers.py).

Usage: python -m helpers.silent HOST PORT. Dials until something listens there (up to 120 s), so it may start before
the listener; prints 'ready' once connected; at SIGTERM, 'closed by the other end' if the listening side ended the
connection meanwhile, else 'still open'.
"""
from __future__ import annotations

import select
import signal
import socket
import sys
import time


def main() -> int:
    ended = []
    signal.signal(signal.SIGTERM, lambda *_: ended.append(True))
    end = time.monotonic() + 120
    while True:
        try:
            conn = socket.create_connection((sys.argv[1], int(sys.argv[2])), timeout=0.5)
            break
        except OSError:
            if ended or time.monotonic() > end:
                return 1
            time.sleep(0.01)
    print('ready', flush=True)
    closed = False
    while not ended:
        readable, _, _ = select.select([] if closed else [conn], [], [], 0.2)
        if readable:
            try:
                closed = conn.recv(4096) == b''  # a TLS listener waits for the dialler's hello: it sends nothing first
            except ConnectionResetError:
                closed = True
    print('closed by the other end' if closed else 'still open', flush=True)
    conn.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
