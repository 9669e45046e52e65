"""Every frame on the links of a namespace's interfaces, appended raw to a file, until SIGTERM (needs root; run it in
the namespace of the hosts' bridge, where each host's link ends): what a stranger on the LAN would read.

Usage: python -m helpers.capture FILE. Prints 'ready' once it captures.
"""
from __future__ import annotations

import signal
import socket
import sys

ETH_P_ALL = 0x0003


def main() -> int:
    running = [True]
    signal.signal(signal.SIGTERM, lambda *_: running.__setitem__(0, False))
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.settimeout(0.2)
    print('ready', flush=True)
    with open(sys.argv[1], 'wb') as out:
        while running[0]:
            try:
                out.write(sock.recv(65535))
            except (TimeoutError, socket.timeout):
                continue
    return 0


if __name__ == '__main__':
    sys.exit(main())
