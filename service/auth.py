"""API keys → tenants; with no keys configured, loopback clients only."""

from __future__ import annotations

import hmac
import ipaddress

from fastapi import Request

from .problems import Problem
from .settings import Settings

LOCAL_TENANT = "local"
"""The tenant of every request when no API keys are configured."""


def is_loopback(host: str | None) -> bool:
    """Whether ``host`` is a loopback address."""
    if not host:
        return False
    try:
        return ipaddress.ip_address(host.split("%")[0]).is_loopback
    except ValueError:
        return host == "localhost"


def _require_loopback(client_host: str | None) -> None:
    if not is_loopback(client_host):
        raise Problem(403, "Forbidden", "no API keys are configured, so this server only "
                      "answers loopback clients", slug="loopback-only")


def tenant_for(settings: Settings, authorization: str | None, client_host: str | None) -> str:
    """The tenant a request acts for, or the 401/403 problem."""
    if not settings.api_keys:
        _require_loopback(client_host)
        return LOCAL_TENANT
    scheme, _, key = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not key.strip():
        raise Problem(401, "Unauthorized", "send an API key as 'Authorization: Bearer <key>'",
                      slug="unauthorized", headers={"WWW-Authenticate": "Bearer"})
    key = key.strip()
    for known, tenant in settings.api_keys.items():
        if hmac.compare_digest(known.encode(), key.encode()):
            return tenant
    raise Problem(401, "Unauthorized", "unknown API key", slug="unauthorized",
                  headers={"WWW-Authenticate": 'Bearer error="invalid_token"'})


def tenant(request: Request) -> str:
    """FastAPI dependency: the tenant of the request."""
    settings: Settings = request.app.state.runtime.settings
    client = request.client.host if request.client else None
    return tenant_for(settings, request.headers.get("authorization"), client)


def metrics_access(settings: Settings, authorization: str | None, client_host: str | None
                   ) -> None:
    """Let a scrape of /metrics through, or raise the 401/403 problem: with
    ``metrics_token`` set, that bearer token; without, anyone when API keys are configured
    (the scraper's network is trusted, as Prometheus expects) and loopback clients only when
    none are."""
    token = settings.metrics_token
    if token is None:
        if not settings.api_keys:
            _require_loopback(client_host)
        return
    scheme, _, key = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not hmac.compare_digest(
            key.strip().encode(), token.get_secret_value().encode()):
        raise Problem(401, "Unauthorized", "/metrics needs 'Authorization: Bearer <metrics "
                      "token>' (BONEFIT_METRICS_TOKEN)", slug="unauthorized",
                      headers={"WWW-Authenticate": "Bearer"})


def metrics_guard(request: Request) -> None:
    """FastAPI dependency: :func:`metrics_access` for the request."""
    settings: Settings = request.app.state.runtime.settings
    client = request.client.host if request.client else None
    metrics_access(settings, request.headers.get("authorization"), client)
