"""stdout and stderr that outlive their reader, for the commands whose records are their files (cli.PRINTERS are not)."""
from __future__ import annotations

import fcntl
import io
import os
import sys


class Outlasting(io.TextIOBase):
    """stdout that outlives its reader: once the pipe closes, what is printed goes to /dev/null, and the job goes on.

    `up ... | head -2` must not cut a run's records at the step the reader left.
    """

    def __init__(self, stream: 'io.TextIOBase') -> None:
        self._stream = stream

    def _closed_pipe(self) -> None:
        os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._closed_pipe()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._closed_pipe()
            try:
                self._stream.flush()  # what was buffered goes to /dev/null now
            except BrokenPipeError:  # pragma: no cover - the descriptor now points at /dev/null
                pass

    def fileno(self) -> int:
        return self._stream.fileno()

    def isatty(self) -> bool:
        return self._stream.isatty()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return self._stream.encoding


def standard_streams() -> None:
    """A command started with its standard streams closed (`sim ... >&- 2>&-`) runs as if they went to /dev/null.

    A closed descriptor is taken by the first file opened after it: ./uav-flock's own script sits on descriptor 2
    when bash is started with 2 closed, read-only, and Python's sys.stderr then raises EBADF at the first note, and
    a records file opened on 1 would take in what is printed.
    """
    for fd in (0, 1, 2):
        try:
            mode = fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE
        except OSError:
            mode = None
        if mode is None or (fd > 0 and mode == os.O_RDONLY):
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    for name, fd in (('stdin', 0), ('stdout', 1), ('stderr', 2)):
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, 'r' if fd == 0 else 'w', buffering=-1 if fd == 0 else 1, closefd=False))
