"""Vehicle events pushed over HTTP (``publish.py``) to a real local HTTP server."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gst_trafficcal.errors import InputError
from gst_trafficcal.publish import EventPoster, check_url, redacted

from .conftest import Receiver, closed_port


@pytest.fixture
def receiver():
    r = Receiver()
    yield r
    r.close()


def test_every_event_arrives_in_order_as_json(receiver):
    poster = EventPoster(receiver.url)
    for i in range(20):
        poster.post({"id": i, "speed_kmh": np.float64(50.0 + i), "lane": np.int64(1), "reason": ""})
    stats = poster.close()
    assert stats.sent == 20 and stats.complete, stats
    assert [b["id"] for b in receiver.bodies] == list(range(20))
    assert receiver.bodies[3] == {"id": 3, "speed_kmh": 53.0, "lane": 1, "reason": ""}
    assert receiver.headers[0]["Content-Type"] == "application/json"


def test_a_receiver_that_fails_for_a_while_gets_the_event_again():
    r = Receiver(statuses=[503, 500])
    try:
        poster = EventPoster(r.url, backoff=0.05)
        poster.post({"id": 7})
        stats = poster.close()
    finally:
        r.close()
    assert stats.sent == 1 and stats.complete and [b["id"] for b in r.bodies] == [7]


def test_a_refused_event_is_not_retried_and_is_said_once():
    r = Receiver(statuses=[400, 400])
    try:
        poster = EventPoster(r.url, backoff=0.05)
        poster.post({"id": 1})
        poster.post({"id": 2})
        deadline = time.monotonic() + 5
        while poster.stats().failed < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        problem = poster.new_problem()
        assert problem == f"{r.url}: HTTP 400 Bad Request" and poster.new_problem() is None
        stats = poster.close()
    finally:
        r.close()
    assert (stats.sent, stats.failed) == (0, 2) and r.bodies == []


def test_an_unreachable_receiver_never_holds_the_caller_up():
    url = f"http://127.0.0.1:{closed_port()}/hook"
    poster = EventPoster(url, retries=2, backoff=0.05, queue_size=5)
    t0 = time.monotonic()
    for i in range(50):
        poster.post({"id": i})
    assert time.monotonic() - t0 < 0.5  # queued, not sent, by the caller
    stats = poster.close(timeout=2.0)
    assert stats.sent == 0 and stats.failed + stats.dropped == 50 and stats.dropped >= 45, stats
    assert stats.last_error.startswith(f"{url}: ") and "refused" in stats.last_error.lower()


def test_a_receiver_that_does_not_answer_costs_at_most_the_close_timeout():
    r = Receiver(delay=3.0)
    try:
        poster = EventPoster(r.url, timeout=10.0)
        poster.post({"id": 1})
        poster.post({"id": 2})
        t0 = time.monotonic()
        stats = poster.close(timeout=0.5)
        assert time.monotonic() - t0 < 1.5
    finally:
        r.close()
    assert stats.sent == 0 and stats.dropped == 2


def test_credentials_in_the_url_are_basic_auth_and_never_shown(receiver):
    secret = receiver.url.replace("http://", "http://ops:s%40cret@")
    poster = EventPoster(secret)
    poster.post({"id": 1})
    poster.close()
    assert receiver.headers[0]["Authorization"] == "Basic b3BzOnNAY3JldA=="  # ops:s@cret
    assert "cret" not in poster.shown_url and redacted(secret).startswith("http://ops:***@127.0.0.1:")


@pytest.mark.parametrize("url", ["ftp://host/x", "localhost:8080/events", "http:///nohost", ""])
def test_anything_but_an_http_url_is_an_error_naming_it(url):
    with pytest.raises(InputError, match="is not an http:// or https:// URL"):
        check_url(url)


def _header(headers: dict, name: str) -> str | None:
    """A header by name, whatever case the client sent it in."""
    return next((v for k, v in headers.items() if k.lower() == name.lower()), None)


def test_a_shared_secret_signs_every_post_and_the_receiver_can_check_it(receiver, monkeypatch):
    """TRAFFICCAL_EVENTS_SECRET set: each POST carries the HMAC-SHA256 of its exact body, which a receiver
    recomputes with the standard library; none without it."""
    import hashlib
    import hmac

    from gst_trafficcal.publish import SECRET_ENV, SIGNATURE_HEADER, signature

    monkeypatch.setenv(SECRET_ENV, "correct horse")
    poster = EventPoster(receiver.url)
    for i in range(3):
        poster.post({"id": i, "speed_kmh": 80.0 + i})
    assert poster.close().sent == 3
    for body, headers in zip(receiver.raw, receiver.headers):
        expected = "sha256=" + hmac.new(b"correct horse", body, hashlib.sha256).hexdigest()
        assert hmac.compare_digest(_header(headers, SIGNATURE_HEADER), expected)
        assert signature("correct horse", body) == expected
        assert signature("wrong", body) != expected and signature("correct horse", body + b" ") != expected
    monkeypatch.delenv(SECRET_ENV)
    poster = EventPoster(receiver.url)
    poster.post({"id": 9})
    poster.close()
    assert _header(receiver.headers[-1], SIGNATURE_HEADER) is None
