"""stdout and stderr that outlive their reader, for the commands whose records are their files (cli.PRINTERS are not)."""
from __future__ import annotations

import io
import os


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
