"""The one exception type of the client: an RFC 9457 problem document from the service."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class ProblemError(Exception):
    """The service answered with a problem (or a job ended with one).

    Attributes
    ----------
    problem : dict
        The RFC 9457 document: ``type``, ``title``, ``status``, ``detail`` and extension
        members such as ``field``, ``line`` or ``sensor``.
    status : int
        HTTP status (or the status recorded in a failed job's problem).
    job : dict or None
        The job's JSON when the problem ended a job (``status`` ``failed`` or ``cancelled``).
    """

    def __init__(self, problem: Mapping[str, Any], *, job: Mapping[str, Any] | None = None
                 ) -> None:
        self.problem = dict(problem)
        self.status = int(self.problem.get("status") or 0)
        self.title = str(self.problem.get("title") or "Error")
        self.detail = str(self.problem.get("detail") or "")
        self.job = dict(job) if job is not None else None
        where = ", ".join(f"{k} {self.problem[k]}" for k in ("field", "sensor", "line", "column")
                          if self.problem.get(k) is not None)
        super().__init__(f"{self.status} {self.title}: {self.detail}"
                         + (f" ({where})" if where else ""))


def problem_of(status: int, content_type: str, body: bytes) -> dict[str, Any]:
    """The problem document of an error response, or one made up from a non-JSON body."""
    import json

    if "json" in content_type:
        try:
            doc = json.loads(body)
        except ValueError:
            doc = None
        if isinstance(doc, dict):
            doc.setdefault("status", status)
            return doc
    text = body.decode("utf-8", "replace").strip()[:500]
    return {"type": "about:blank", "title": f"HTTP {status}", "status": status,
            "detail": text or f"the server answered {status}"}
