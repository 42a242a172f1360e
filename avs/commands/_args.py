"""Argument types that check their range before anything starts, and a parser whose errors
are one line."""

from __future__ import annotations

import argparse
from pathlib import Path

#: the built-in scenes (``services/sim/scenes/*.xml``) and robots, for the options' help
#: without importing the simulator (``services.sim.scene.BUILTIN_SCENES``, ``ROBOTS``)
_SCENES_DIR = Path(__file__).resolve().parents[2] / "services" / "sim" / "scenes"
SCENES = tuple(sorted(p.stem for p in _SCENES_DIR.glob("*.xml")))
ROBOTS = ("armar6", "armar3")


def scene_help(what: str = "the scene") -> str:
    return f"{what}: a built-in scene ({', '.join(SCENES)}) or an MJCF file"


ROBOT_HELP = f"the robot ({', '.join(ROBOTS)})"


class Help(argparse.RawDescriptionHelpFormatter):
    """The description as written; every option's help ends with its default, where it has
    one and the help does not already say it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            default is None
            or isinstance(default, bool)
            or default == ""
            or default is argparse.SUPPRESS
            or not action.option_strings
            or "default" in text
        ):
            return text
        if isinstance(default, list | tuple):
            default = ",".join(map(str, default))
        shown = str(default).replace("%", "%%")
        return f"{text} (default {shown})" if text else f"default {shown}"


def explain(parser: argparse.ArgumentParser) -> None:
    """``Help`` for ``parser`` and every subcommand's parser under it."""
    parser.formatter_class = Help
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                explain(sub)


class OneLineParser(argparse.ArgumentParser):
    """``prog: message (--help for usage)`` on stderr and exit 2, not the usage block. No
    prefix abbreviations (``allow_abbrev=False``, also for the subcommands' parsers): a flag
    added later must not change what an abbreviation meant (``--view`` for ``--views``)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (--help for usage)\n")


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def positive_int(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def positive_float(text: str) -> float:
    value = _number(text)
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def non_negative_float(text: str) -> float:
    value = _number(text)
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a number ≥ 0, got {text}")
    return value


def non_negative_int(text: str) -> int:
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be ≥ 0, got {value}")
    return value


FUSIONS = ("pc", "sg", "pc+sg")


def fusion_list(text: str) -> list[str]:
    """A comma list of fusion modes (``pc,sg,pc+sg``), each known, none twice."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise argparse.ArgumentTypeError("no fusion mode given")
    unknown = [n for n in names if n not in FUSIONS]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown fusion {', '.join(map(repr, unknown))} (choose from {', '.join(FUSIONS)})"
        )
    if len(set(names)) < len(names):
        raise argparse.ArgumentTypeError(f"a fusion mode given twice in {text!r}")
    return names


def add_console_arguments(parser: argparse.ArgumentParser) -> None:
    """``--verbose``: the long commands' services' log lines live on the console too (they are
    always in ``DIR/logs/``)."""
    parser.add_argument(
        "--verbose",
        "-v",
        action="store_true",
        help="show the services' log lines live (always written to OUT/logs/<service>.log)",
    )


def add_playback_arguments(parser: argparse.ArgumentParser, source: str) -> argparse._ArgumentGroup:
    """``--rate``, ``--start``, ``--limit`` and ``--wait`` of a replay of ``source`` (a bag, a
    dataset): the ``playback`` group both replays share, returned for their own flags."""
    play = parser.add_argument_group("playback")
    play.add_argument("--rate", type=non_negative_float, default=1.0, metavar="F",
                      help=f"speed factor on the {source}'s timing (default 1; 0: as fast as "
                      "possible)")  # fmt: skip
    play.add_argument("--start", type=non_negative_float, default=0.0, metavar="S",
                      help=f"skip the {source}'s first S s")  # fmt: skip
    play.add_argument("--limit", type=non_negative_int, default=0, metavar="N",
                      help="stop after N frames (0: all)")  # fmt: skip
    play.add_argument("--wait", type=non_negative_float, default=10.0, metavar="S",
                      help="wait up to S s for a subscriber before the first frame "
                      "(default 10)")  # fmt: skip
    return play
