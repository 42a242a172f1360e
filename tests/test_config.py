"""Settings come from defaults, then AVS_* variables, then flags; bad values name their source."""

from __future__ import annotations

import argparse
from typing import ClassVar

import pytest
from pydantic import Field

from services.common.config import ServiceSettings, SettingsError


class DemoSettings(ServiceSettings):
    """A demo service."""

    SERVICE: ClassVar[str] = "demo"
    frame_rate: float = Field(15.0, gt=0, description="frames per second")
    cameras: list[str] = Field(default_factory=lambda: ["head_rgbd"], description="cameras")
    noise: bool = Field(True, description="depth noise")


def test_defaults():
    s = DemoSettings.from_args([], env={})
    assert s.frame_rate == 15.0 and s.cameras == ["head_rgbd"] and s.noise
    assert s.robot == "armar6" and s.mode is None and s.connect == []


def test_environment_then_flags():
    env = {
        "AVS_DEMO_FRAME_RATE": "30",
        "AVS_CONNECT": "tcp/127.0.0.1:1,tcp/127.0.0.1:2",
        "AVS_MODE": "client",
        "AVS_DEMO_NOISE": "off",
    }
    s = DemoSettings.from_args([], env=env)
    assert s.frame_rate == 30.0 and not s.noise and s.mode == "client"
    assert s.connect == ["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"]
    s = DemoSettings.from_args(["--frame-rate", "5", "--noise", "--cameras", "a,b"], env=env)
    assert s.frame_rate == 5.0 and s.noise and s.cameras == ["a", "b"]


def test_shared_fields_use_the_plain_prefix():
    assert DemoSettings.env_name("connect") == "AVS_CONNECT"
    assert DemoSettings.env_name("instance") == "AVS_INSTANCE"
    assert DemoSettings.env_name("frame_rate") == "AVS_DEMO_FRAME_RATE"


def test_bad_values_name_the_variable_or_flag():
    with pytest.raises(SettingsError, match="AVS_DEMO_FRAME_RATE"):
        DemoSettings.from_namespace(argparse.Namespace(), env={"AVS_DEMO_FRAME_RATE": "-1"})
    with pytest.raises(SettingsError, match="--robot"):
        DemoSettings.from_namespace(argparse.Namespace(robot="ar/mar"), env={})


def test_bad_flag_exits_with_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        DemoSettings.from_args(["--frame-rate", "fast"], env={})
    assert info.value.code == 2
    assert "--frame-rate" in capsys.readouterr().err


def test_help_lists_every_field_with_its_variable(capsys):
    with pytest.raises(SystemExit):
        DemoSettings.from_args(["--help"], env={})
    out = capsys.readouterr().out
    for text in ("--frame-rate", "AVS_DEMO_FRAME_RATE", "--connect", "AVS_CONNECT", "--no-noise"):
        assert text in out
