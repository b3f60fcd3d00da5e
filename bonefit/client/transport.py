"""Retries of transient failures: which failures, how long to wait, with what headers."""

from __future__ import annotations

import email.utils
import random
import time
from dataclasses import dataclass

import httpx

TRANSIENT_STATUS = frozenset({429, 502, 503, 504})
"""Statuses worth another try: rate limited, or a proxy/server briefly away."""


@dataclass(frozen=True)
class RetryPolicy:
    """How transient failures are retried.

    Attributes
    ----------
    attempts : int
        Tries of one request in all (the first included).
    backoff : float
        First wait, seconds; doubled each retry (with ±25 % jitter) up to ``max_delay``.
    max_delay : float
        Longest wait between two tries, seconds (a ``Retry-After`` is honoured up to
        ``max_retry_after``).
    max_retry_after : float
        Longest ``Retry-After`` obeyed, seconds.
    """

    attempts: int = 10
    backoff: float = 0.25
    max_delay: float = 8.0
    max_retry_after: float = 60.0

    def delay(self, retry: int, retry_after: float | None = None) -> float:
        """Seconds to wait before retry number ``retry`` (0 for the first retry)."""
        if retry_after is not None:
            return min(max(retry_after, 0.0), self.max_retry_after)
        base = min(self.backoff * 2.0 ** retry, self.max_delay)
        return base * random.uniform(0.75, 1.25)


NO_RETRY = RetryPolicy(attempts=1)
"""Fail on the first transient error."""


def is_transient_error(exc: BaseException) -> bool:
    """Connection refused or reset, a timeout, a dropped stream: worth another try."""
    return isinstance(exc, httpx.TransportError) and not isinstance(
        exc, httpx.UnsupportedProtocol | httpx.LocalProtocolError)


def is_transient_status(status: int) -> bool:
    """An HTTP status worth another try."""
    return status in TRANSIENT_STATUS


def retry_after(response: httpx.Response) -> float | None:
    """The ``Retry-After`` header in seconds (delta-seconds or an HTTP date), if any."""
    value = response.headers.get("retry-after")
    if not value:
        return None
    value = value.strip()
    if value.isdigit():
        return float(value)
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    return max(when.timestamp() - time.time(), 0.0)


def auth_headers(api_key: str | None) -> dict[str, str]:
    """The bearer header for ``api_key`` (none in loopback-only mode)."""
    return {"Authorization": f"Bearer {api_key}"} if api_key else {}
