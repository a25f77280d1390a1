"""A long command that outlives the terminal it was started from (an SSH session closed, a ``| tee`` killed).

When the terminal goes away, every write to it fails (EIO on a hung-up terminal, EPIPE on a pipe without reader):
``trafficcal run``, ended by the SIGHUP that comes with it, then died of the first line it printed — before it
completed its outputs and said "interrupted" in status.json.  :func:`quiet_when_the_terminal_is_gone` makes
``sys.stdout`` and ``sys.stderr`` drop what they cannot write from the first such failure on: the files are the
run's record, the screen only its echo.

What the screen said that an operator must still read afterwards — the warnings, the errors, how the run ended —
goes to a :class:`RunLog` too (``--out/run.log``): everything written to ``sys.stderr`` inside the block, and what
:func:`say` is given, each line with its date and time (what :func:`say` and :func:`stderr_console` print on stderr
is not logged as it is shown: a warning goes in once as its plain line, a progress bar's redrawing not at all).

Diagnostics — warnings, progress, how a run ended — go to stderr, results to stdout (docs/run.md).  A run whose
SSH session closed, or that was started detached, ends with its error there, not only in status.json.
"""

from __future__ import annotations

import errno
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

LOG_MAX_BYTES = 1_000_000  # run.log is moved to run.log.1 (the one before dropped) when it grows past this


class RunLog:
    """A log file of dated lines, appended (a service restarted into the same --out adds to it) and kept to
    ``max_bytes`` and one earlier file (``NAME.1``).  A write that fails is said once on stderr and never stops the
    run; the file is made at its first line."""

    def __init__(self, path: str | Path, max_bytes: int = LOG_MAX_BYTES) -> None:
        self.path, self.max_bytes, self._failed, self._partial = Path(path), int(max_bytes), False, ""
        self.closed = False  # nothing more is written (a refused run removed the file with the rest)

    def close(self) -> None:
        self.closed = True

    def line(self, text: str) -> None:
        """``text`` (one line or several) appended with this machine's date and time."""
        from ..run_status import now_iso

        stamp = now_iso()
        self._append("".join(f"{stamp} {part}\n" for part in text.rstrip("\n").split("\n")))

    def stream(self, text: str) -> None:
        """Text as a stream writes it (lines in pieces): each line logged once it is complete."""
        self._partial += text
        if "\n" in self._partial:
            done, self._partial = self._partial.rsplit("\n", 1)
            self.line(done)

    def flush(self) -> None:
        """The last line of :meth:`stream` if it has no end of line yet."""
        if self._partial:
            text, self._partial = self._partial, ""
            self.line(text)

    def _append(self, text: str) -> None:
        import os

        if self.closed:
            return
        try:
            if self.path.is_file() and self.path.stat().st_size + len(text) > self.max_bytes:
                os.replace(self.path, self.path.with_name(self.path.name + ".1"))
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(text)
        except OSError as exc:
            if not self._failed:
                self._failed = True
                try:
                    sys.__stderr__.write(f"trafficcal: warning: {self.path}: cannot write the run's log "
                                         f"({exc.strerror or exc}); the run goes on without it\n")
                except (OSError, AttributeError, ValueError):
                    pass


_log: RunLog | None = None  # the log of the command running (quiet_when_the_terminal_is_gone's)


class _StderrUnlogged:
    """``sys.stderr`` as it is at each write (quiet once the terminal is gone), but kept out of the run's log: what
    :func:`say` prints is logged as one plain line, a progress bar's redrawing not at all."""

    def write(self, text: str) -> int:
        err = sys.stderr
        return err.write_unlogged(text) if isinstance(err, _Echo) else err.write(text)

    def flush(self) -> None:
        sys.stderr.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(sys.stderr, name)


def stderr_console() -> Any:
    """A rich Console on stderr, for diagnostics (warnings, progress): stdout holds the results only, so a run's
    ``> file`` gets those and the terminal still shows what goes wrong (docs/run.md)."""
    from rich.console import Console

    return Console(file=_StderrUnlogged())  # type: ignore[arg-type]


def say(console: Any, text: str, style: str = "yellow", label: str = "warning") -> None:
    """Print "label: text" (the label in ``style``) on stderr, whichever ``console`` prints the command's results,
    and put it in the run's log, if there is one."""
    stderr_console().print(f"[{style}]{label}[/]: {text}", highlight=False)
    if _log is not None:
        _log.line(f"{label}: {text}")


def log_line(text: str) -> None:
    """Put ``text`` in the run's log only (nothing when there is none)."""
    if _log is not None:
        _log.line(text)

GONE = (errno.EIO, errno.EPIPE, errno.ENXIO)  # a hung-up terminal, a pipe whose reader left, a terminal removed


class _Echo:
    """A text stream that passes everything on to ``stream`` until a write fails because the reader is gone, then
    drops what it is given (``gone`` says so); other attributes are the stream's."""

    def __init__(self, stream: TextIO, log: RunLog | None = None) -> None:
        self._stream, self.gone, self._log = stream, False, log

    def write(self, text: str) -> int:
        if self._log is not None:
            self._log.stream(text)
        written = self._while_there(self._stream.write, text)
        return len(text) if written is None else written

    def write_unlogged(self, text: str) -> int:
        """``write`` without the log (:class:`_StderrUnlogged`)."""
        written = self._while_there(self._stream.write, text)
        return len(text) if written is None else written

    def flush(self) -> None:
        self._while_there(self._stream.flush)

    def _while_there(self, call: Any, *args: Any) -> Any:
        """``call(*args)`` while the reader is there; None once it is gone (from the first write that says so)."""
        if self.gone:
            return None
        try:
            return call(*args)
        except OSError as exc:
            if exc.errno not in GONE:
                raise
            self.gone = True
            return None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def quiet_when_the_terminal_is_gone(log: RunLog | None = None) -> Iterator[None]:
    """``sys.stdout`` and ``sys.stderr`` that go quiet once their reader is gone, inside the block.  Once one has gone
    quiet it stays in place afterwards too: the interpreter's last flush at exit would fail on the dead stream.
    ``log``: what is written to stderr inside the block, and what :func:`say` and :func:`log_line` are given, goes
    there too (an error that leaves the block: "trafficcal: error: ..." as the command line prints it)."""
    global _log
    from ..errors import TrafficcalError

    echoes = [_Echo(sys.stdout), _Echo(sys.stderr, log)]
    sys.stdout, sys.stderr = echoes  # type: ignore[assignment]
    _log = log
    try:
        yield
    except TrafficcalError as exc:
        if log is not None:
            log.flush()
            log.line(f"trafficcal: error: {exc}")
        raise
    except KeyboardInterrupt:
        if log is not None:
            log.flush()
            log.line("trafficcal: stopped at once (a second Ctrl-C, SIGTERM or SIGHUP)")
        raise
    finally:
        if log is not None:
            log.flush()
        _log = None
        out, err = echoes
        err._log = None
        if not (out.gone or err.gone):
            sys.stdout, sys.stderr = out._stream, err._stream
