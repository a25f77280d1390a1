"""Vehicle events pushed to another system as they happen: one HTTP POST (JSON) per vehicle that leaves.

What a video-management or traffic-data system integrates with: a webhook URL it serves.  The video must never
wait for it, so :class:`EventPoster` sends from a background thread: :meth:`EventPoster.post` only queues.  A
receiver that is down or slow is retried (``retries`` attempts per event, backing off; while it stays down, one
attempt per event until one gets through), the queue is bounded
(``queue_size`` events; beyond it the oldest are dropped and counted), and :meth:`EventPoster.close` gives the
queue ``timeout`` seconds to drain at the end of the stream.  Every event is also in the element's files, so a
receiver that was away loses nothing that cannot be re-sent from them.  ``http://user:password@host/...`` sends
HTTP basic authentication.  With a shared secret (``secret``, by default the environment's
``TRAFFICCAL_EVENTS_SECRET``: never in a pipeline description, a command line or a log), every POST is signed as
GitHub and Stripe sign theirs: ``X-Trafficcal-Signature-256: sha256=<hex HMAC-SHA256 of the body>``, so the
receiver can tell our events from anyone else's and from altered ones (:func:`signature`).
"""

from __future__ import annotations

import base64
import collections
import hashlib
import hmac
import json
import os
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from typing import Any, Mapping

from .errors import InputError

USER_AGENT = "gst-trafficcal"
SECRET_ENV = "TRAFFICCAL_EVENTS_SECRET"  # the shared secret that signs every POST, when set
SIGNATURE_HEADER = "X-Trafficcal-Signature-256"


def signature(secret: str, body: bytes) -> str:
    """The signature header's value for ``body``: ``sha256=`` and the hex HMAC-SHA256 under ``secret``.  A receiver
    computes the same over the raw body it got and compares with ``hmac.compare_digest``."""
    return "sha256=" + hmac.new(secret.encode("utf-8"), body, hashlib.sha256).hexdigest()


@dataclass(frozen=True)
class PostStats:
    """What happened to the events handed to the poster."""

    sent: int = 0
    failed: int = 0  # given up after every retry
    dropped: int = 0  # pushed out of a full queue, or still queued when the poster closed
    last_error: str = ""

    @property
    def complete(self) -> bool:
        return self.failed == 0 and self.dropped == 0


def check_url(url: str, what: str = "events-url") -> tuple[str, dict[str, str]]:
    """(the URL without credentials, the request headers); InputError for anything but an http(s) URL."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise InputError(f"{what}: {url!r} is not an http:// or https:// URL")
    headers = {"Content-Type": "application/json", "User-Agent": USER_AGENT}
    if parts.username is not None:
        user = urllib.parse.unquote(parts.username)
        password = urllib.parse.unquote(parts.password or "")
        headers["Authorization"] = "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode("ascii")
        host = parts.hostname + (f":{parts.port}" if parts.port else "")
        if ":" in parts.hostname:  # IPv6 literal
            host = f"[{parts.hostname}]" + (f":{parts.port}" if parts.port else "")
        url = urllib.parse.urlunsplit((parts.scheme, host, parts.path, parts.query, parts.fragment))
    return url, headers


def redacted(url: str) -> str:
    """The URL for messages: without a password."""
    parts = urllib.parse.urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.replace(f":{parts.password}@", ":***@", 1)
    return urllib.parse.urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


class EventPoster:
    """POSTs JSON objects to ``url`` from a background thread (see the module doc)."""

    def __init__(self, url: str, timeout: float = 5.0, retries: int = 3, queue_size: int = 1000,
                 backoff: float = 0.5, secret: str | None = None) -> None:
        if timeout <= 0 or retries < 1 or queue_size < 1 or backoff < 0:
            raise InputError("events-url: timeout, retries and queue size must be positive")
        self.url, self._headers = check_url(url)
        self._secret = os.environ.get(SECRET_ENV, "") if secret is None else secret  # "": unsigned
        self.shown_url = redacted(url)
        self.timeout, self.retries, self.backoff = float(timeout), int(retries), float(backoff)
        self._queue: collections.deque[bytes] = collections.deque()
        self._queue_size = int(queue_size)
        self._cond = threading.Condition()
        self._closing = False
        self._inflight = False  # an event taken off the queue and being sent
        self._final: PostStats | None = None  # the count when the poster closed
        self._down = False  # the last event could not be sent (the sending thread's own flag)
        self._sent = self._failed = self._dropped = 0
        self._last_error = ""
        self._reported = ""
        self._thread = threading.Thread(target=self._run, name="trafficcal-events-url", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ caller's side
    def post(self, fields: Mapping[str, Any]) -> None:
        """Queue one event (never blocks; a full queue drops its oldest event)."""
        body = json.dumps(dict(fields), allow_nan=False, default=_plain).encode("utf-8")
        with self._cond:
            if self._closing:
                raise RuntimeError("the poster is closed")
            if len(self._queue) >= self._queue_size:
                self._queue.popleft()
                self._dropped += 1
            self._queue.append(body)
            self._cond.notify()

    def new_problem(self) -> str | None:
        """The latest error, once, when it differs from the one reported before (for a warning); None otherwise."""
        with self._cond:
            if self._last_error and self._last_error != self._reported:
                self._reported = self._last_error
                return self._last_error
        return None

    def stats(self) -> PostStats:
        with self._cond:
            if self._final is not None:
                return self._final
            return PostStats(self._sent, self._failed, self._dropped, self._last_error)

    def close(self, timeout: float = 10.0) -> PostStats:
        """Send what is queued (at most ``timeout`` seconds more), stop the thread; what is left counts as
        dropped."""
        deadline = time.monotonic() + timeout
        with self._cond:
            self._closing = True
            self._cond.notify_all()
            while (self._queue or self._inflight) and self._thread.is_alive():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            self._dropped += len(self._queue) + int(self._inflight)  # a receiver still not answering: given up
            self._queue.clear()
            self._final = PostStats(self._sent, self._failed, self._dropped, self._last_error)
            self._cond.notify_all()
        self._thread.join(timeout=max(0.0, deadline - time.monotonic()) + 0.1)
        return self._final

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue:
                    return
                body = self._queue.popleft()
                self._inflight = True
            ok, error = self._send(body)
            with self._cond:
                self._inflight = False
                if ok:
                    self._sent += 1
                else:
                    self._failed += 1
                    self._last_error = error
                self._cond.notify_all()

    def _send(self, body: bytes) -> tuple[bool, str]:
        error = ""
        headers = dict(self._headers, **{SIGNATURE_HEADER: signature(self._secret, body)}) if self._secret \
            else self._headers
        # while the receiver is down each event gets one attempt, so the queue does not wait on back-offs
        for attempt in range(1 if self._down else self.retries):
            if attempt:
                time.sleep(self.backoff * 2 ** (attempt - 1))
            request = urllib.request.Request(self.url, data=body, headers=headers, method="POST")
            try:
                with urllib.request.urlopen(request, timeout=self.timeout) as response:
                    response.read()
                self._down = False
                return True, ""
            except urllib.error.HTTPError as exc:
                error = f"{self.shown_url}: HTTP {exc.code} {exc.reason}"
                if 400 <= exc.code < 500 and exc.code not in (408, 429):  # the receiver refuses it: no retry
                    break
            except (urllib.error.URLError, OSError, ValueError) as exc:
                reason = getattr(exc, "reason", exc)
                error = f"{self.shown_url}: {reason}"
        self._down = True
        return False, error


def _plain(value: Any) -> Any:
    """numpy scalars and the like in an event: their Python value."""
    item = getattr(value, "item", None)
    if callable(item):
        return item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
