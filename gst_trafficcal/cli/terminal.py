"""A long command that outlives the terminal it was started from (an SSH session closed, a ``| tee`` killed).

When the terminal goes away, every write to it fails (EIO on a hung-up terminal, EPIPE on a pipe without reader):
``trafficcal run``, ended by the SIGHUP that comes with it, then died of the first line it printed — before it
completed its outputs and said "interrupted" in status.json.  :func:`quiet_when_the_terminal_is_gone` makes
``sys.stdout`` and ``sys.stderr`` drop what they cannot write from the first such failure on: the files are the
run's record, the screen only its echo.
"""

from __future__ import annotations

import errno
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO

GONE = (errno.EIO, errno.EPIPE, errno.ENXIO)  # a hung-up terminal, a pipe whose reader left, a terminal removed


class _Echo:
    """A text stream that passes everything on to ``stream`` until a write fails because the reader is gone, then
    drops what it is given (``gone`` says so); other attributes are the stream's."""

    def __init__(self, stream: TextIO) -> None:
        self._stream, self.gone = stream, False

    def write(self, text: str) -> int:
        if not self.gone:
            try:
                return self._stream.write(text)
            except OSError as exc:
                if exc.errno not in GONE:
                    raise
                self.gone = True
        return len(text)

    def flush(self) -> None:
        if not self.gone:
            try:
                self._stream.flush()
            except OSError as exc:
                if exc.errno not in GONE:
                    raise
                self.gone = True

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def quiet_when_the_terminal_is_gone() -> Iterator[None]:
    """``sys.stdout`` and ``sys.stderr`` that go quiet once their reader is gone, inside the block.  Once one has gone
    quiet it stays in place afterwards too: the interpreter's last flush at exit would fail on the dead stream."""
    echoes = [_Echo(sys.stdout), _Echo(sys.stderr)]
    sys.stdout, sys.stderr = echoes  # type: ignore[assignment]
    try:
        yield
    finally:
        out, err = echoes
        if not (out.gone or err.gone):
            sys.stdout, sys.stderr = out._stream, err._stream
