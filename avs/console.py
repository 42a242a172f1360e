"""The console of the long commands (``avs run``, ``explore``, ``compare``, ``fuse``): one
progress display (rich) and a summary on the console; the services' output and this process's
own log lines in ``DIR/logs/`` (``--verbose`` shows the services' lines live as well).

On a terminal the progress bar redraws in place; captured (CI, a pipe) rich prints its final
state once, so the whole output stays a handful of lines.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
)

from services.common.log import TextFormatter

#: the console every long command prints its progress, warnings and live logs to (stderr)
console = Console(stderr=True, highlight=False, soft_wrap=True)
if not console.is_terminal:  # captured: one whole line, not cut to rich's default 80 columns
    console.width = 200


class ConsoleHandler(logging.Handler):
    """Log records through the rich console, so a progress bar on screen stays intact."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            console.print(self.format(record), markup=False)
        except Exception:  # logging must never raise into the caller
            self.handleError(record)


def log_to(log_dir: Path, command: str) -> None:
    """This process's log lines to ``log_dir/avs.log`` (at the command's ``--log-level``);
    only warnings and errors on the console."""
    log_dir.mkdir(parents=True, exist_ok=True)
    formatter = TextFormatter(f"avs[{command}]")
    to_file = logging.FileHandler(log_dir / "avs.log")
    to_file.setFormatter(formatter)
    on_console = ConsoleHandler(logging.WARNING)
    on_console.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    logging.getLogger().handlers[:] = [to_file, on_console]


def progress() -> Progress:
    """A progress display: a description, a bar, views done of all, a free-text ``info``
    field (the current F1, unknown voxels, path cost) and the elapsed time."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(bar_width=30),
        MofNCompleteColumn(),
        TextColumn("{task.fields[info]}"),
        TimeElapsedColumn(),
        console=console,
    )


class Follow:
    """Print the lines appended to every ``*.log`` under a directory (``--verbose``), each
    prefixed by its file's name (and folder, below the top), until stopped."""

    def __init__(self, log_dir: Path, every: float = 0.2) -> None:
        self.log_dir, self.every = log_dir, every
        self._offsets: dict[Path, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="follow-logs", daemon=True)

    def start(self) -> Follow:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._drain()

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self._drain()

    def _drain(self) -> None:
        for path in sorted(self.log_dir.rglob("*.log")):
            if path.name == "avs.log":
                continue  # this process's own lines are on the console already
            offset = self._offsets.get(path, 0)
            try:
                with path.open("rb") as f:
                    f.seek(offset)
                    chunk = f.read()
            except OSError:
                continue
            end = chunk.rfind(b"\n") + 1  # whole lines only; the rest next time
            if end == 0:
                continue
            self._offsets[path] = offset + end
            name = path.relative_to(self.log_dir).with_suffix("").as_posix()
            name = name.removesuffix("logs/").replace("/logs/", "/")
            for line in chunk[:end].decode(errors="replace").splitlines():
                console.print(f"{name}| {line}", markup=False)


@contextmanager
def following(log_dir: Path, verbose: bool) -> Iterator[None]:
    """With ``verbose``, show the services' log lines live while the block runs."""
    if not verbose:
        yield
        return
    log_dir.mkdir(parents=True, exist_ok=True)
    follower = Follow(log_dir).start()
    try:
        yield
    finally:
        follower.stop()
