"""Typed settings filled from defaults, then environment variables, then command-line flags.

A field ``frame_rate`` of a service ``sim`` is read from ``AVS_SIM_FRAME_RATE`` and
``--frame-rate``; the fields shared by every service (transport, robot, logging) from
``AVS_<FIELD>`` (``AVS_CONNECT``, ``AVS_ROBOT`` …). Lists are comma-separated. Each field's
description is its ``--help`` text.
"""

from __future__ import annotations

import argparse
import inspect
import os
import socket
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import UnionType
from typing import Any, ClassVar, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, SecretStr, ValidationError, field_validator

from schemas.keys import DEFAULT_ROBOT, check_chunk


def _unwrap_optional(t: Any) -> Any:
    if get_origin(t) in (Union, UnionType):
        args = [a for a in get_args(t) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return t


def _is_sequence(t: Any) -> bool:
    return get_origin(_unwrap_optional(t)) in (list, tuple)


def _is_bool(t: Any) -> bool:
    return _unwrap_optional(t) is bool


class SettingsError(ValueError):
    """Settings that do not validate; the text names the variable or flag."""


class Settings(BaseModel):
    """Base of every typed configuration. Subclasses set ``SERVICE`` for their env prefix."""

    model_config = ConfigDict(extra="forbid", validate_default=True)

    #: service name: fields declared below ``BASE`` are read from ``AVS_<SERVICE>_<FIELD>``.
    SERVICE: ClassVar[str] = ""
    BASE: ClassVar[type[BaseModel] | None] = None

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: object) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        base = cls.BASE
        own = set(inspect.get_annotations(cls))
        if base is not None and cls is not base and own & set(base.model_fields):
            raise TypeError(
                f"{cls.__name__} redefines shared settings {sorted(own & set(base.model_fields))}"
            )

    @classmethod
    def env_name(cls, field: str) -> str:
        shared = cls.BASE is not None and field in cls.BASE.model_fields
        prefix = "AVS_" if shared or not cls.SERVICE else f"AVS_{cls.SERVICE.upper()}_"
        return prefix + field.upper()

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """One ``--flag`` per field; values stay strings until pydantic validates them."""
        for name, info in cls.model_fields.items():
            flag = "--" + name.replace("_", "-")
            help_text = (info.description or "") + f" [env {cls.env_name(name)}]"
            if _is_bool(info.annotation):
                parser.add_argument(
                    flag,
                    dest=name,
                    action=argparse.BooleanOptionalAction,
                    default=None,
                    help=help_text,
                )
                continue
            choices = None
            inner = _unwrap_optional(info.annotation)
            if get_origin(inner) is Literal:
                choices = [str(c) for c in get_args(inner)]
            parser.add_argument(
                flag,
                dest=name,
                default=None,
                choices=choices,
                help=help_text,
                metavar="A,B,..." if _is_sequence(info.annotation) else None,
            )

    @classmethod
    def from_namespace(
        cls, namespace: argparse.Namespace, env: Mapping[str, str] | None = None, **overrides: Any
    ):
        """Defaults ← environment ← parsed flags ← ``overrides``."""
        env = os.environ if env is None else env
        values: dict[str, Any] = {}
        source: dict[str, str] = {}
        for name, info in cls.model_fields.items():
            raw = getattr(namespace, name, None)
            where = "--" + name.replace("_", "-")
            if raw is None and cls.env_name(name) in env:
                raw, where = env[cls.env_name(name)], cls.env_name(name)
            if raw is None:
                continue
            if isinstance(raw, str) and _is_sequence(info.annotation):
                raw = [p.strip() for p in raw.split(",") if p.strip()]
            values[name], source[name] = raw, where
        values.update(overrides)
        try:
            return cls(**values)
        except ValidationError as e:
            problems = []
            for err in e.errors(include_url=False):
                field = str(err["loc"][0]) if err["loc"] else ""
                problems.append(f"{source.get(field, field)}: {err['msg']}")
            raise SettingsError("; ".join(problems)) from None

    @classmethod
    def from_args(
        cls,
        argv: Sequence[str] | None = None,
        env: Mapping[str, str] | None = None,
        prog: str | None = None,
    ):
        """Parse ``argv`` (default ``sys.argv[1:]``); a bad value exits with status 2 and a
        one-line message, like any argparse error."""
        parser = argparse.ArgumentParser(
            prog=prog or (f"python -m services.{cls.SERVICE}" if cls.SERVICE else None),
            description=(cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else None,
        )
        cls.add_arguments(parser)
        namespace = parser.parse_args(sys.argv[1:] if argv is None else argv)
        try:
            return cls.from_namespace(namespace, env)
        except SettingsError as e:
            parser.error(str(e))


class TransportSettings(Settings):
    """How to reach the Zenoh network."""

    robot: str = Field(DEFAULT_ROBOT, description="robot name, the second chunk of every key")
    mode: Literal["peer", "client", "router"] | None = Field(
        None, description="Zenoh session mode (default: the config file's, else peer)"
    )
    connect: list[str] = Field(
        default_factory=list, description="endpoints to connect to, e.g. tcp/127.0.0.1:7447"
    )
    listen: list[str] = Field(default_factory=list, description="endpoints to listen on")
    multicast: bool | None = Field(
        None, description="multicast scouting (default: the config file's, else on)"
    )
    zenoh_config: Path | None = Field(None, description="a Zenoh JSON5 config file to start from")
    user: str | None = Field(
        None, description="user name for the router's authentication (and its access control)"
    )
    password: SecretStr | None = Field(None, description="its password (never logged)")
    tls_ca: Path | None = Field(
        None, description="CA certificate that signed the router's (for tls/… endpoints)"
    )

    @field_validator("robot")
    @classmethod
    def _robot_is_chunk(cls, v: str) -> str:
        return check_chunk(v, "robot name")


def default_instance() -> str:
    return f"{socket.gethostname()}-{os.getpid()}".replace("/", "-")


class ServiceSettings(TransportSettings):
    """Settings every service shares: transport, instance name, logging."""

    instance: str = Field(
        default_factory=default_instance, description="instance name (default host-pid)"
    )
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = Field("INFO", description="log level")
    log_format: Literal["text", "json"] = Field("text", description="log line format")
    switch_interval_ms: float = Field(
        0.5,
        gt=0.0,
        le=100.0,
        description="CPython's thread switch interval (default 5 ms): how long a thread that "
        "wants the GIL waits for one that holds it; a node's frame step waits for it at every "
        "compiled call and parallel region (benchmarks/gil_waits.py)",
    )

    @field_validator("instance")
    @classmethod
    def _instance_is_chunk(cls, v: str) -> str:
        return check_chunk(v, "instance name")


TransportSettings.BASE = TransportSettings
ServiceSettings.BASE = ServiceSettings
