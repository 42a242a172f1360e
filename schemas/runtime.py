"""Messages of the service runtime itself: metrics, query errors, the supervisor's report."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from schemas.base import Message, Model, Stamped


class TimingSummary(Model):
    """Processing time of one handler over its recent calls, in milliseconds."""

    count: int = Field(ge=0)
    p50: float = Field(ge=0)
    p90: float = Field(ge=0)
    p99: float = Field(ge=0)
    max: float = Field(ge=0)


class ServiceMetrics(Stamped):
    """Answer of ``metrics/<service>/<instance>``: counters since start and handler timings.
    v2: ``messages_valid``."""

    VERSION: ClassVar[int] = 2

    service: str
    instance: str
    uptime_s: float = Field(ge=0)
    messages_in: dict[str, int] = Field(default_factory=dict, description="per key expression")
    messages_valid: dict[str, int] = Field(
        default_factory=dict,
        description="per key expression: the inputs that decoded and validated (garbage, wrong "
        "schemas and versions are in messages_in only)",
    )
    messages_out: dict[str, int] = Field(default_factory=dict, description="per key expression")
    dropped: dict[str, int] = Field(default_factory=dict, description="per reason")
    processing_ms: dict[str, TimingSummary] = Field(default_factory=dict, description="per handler")
    extra: dict[str, float] = Field(default_factory=dict, description="service-specific gauges")


class QueryError(Message):
    """Payload of an error reply to a query."""

    error: str


class SupervisedService(Model):
    """One service instance ``avs up`` keeps running."""

    service: str
    instance: str
    pid: int | None = None
    state: Literal["starting", "running", "standby", "backoff", "hung", "failed", "stopped"]
    alive: bool = Field(description="its liveliness token (or its standby token) is up")
    restarts: int = Field(ge=0)
    uptime_s: float = Field(ge=0, description="since its current process started")


class SupervisorStatus(Stamped):
    """Answer of ``supervisor``: the expected set of services and how each one is doing."""

    services: list[SupervisedService] = Field(default_factory=list)
