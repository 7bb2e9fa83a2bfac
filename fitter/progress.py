"""Progress reports of long computations: one callback protocol for every caller.

A long computation (`fit_recordings`, `diagnose`, ...) takes a `Progress`
callback and calls it as ``progress(message, fraction)``: `message` is one
line saying what is being done now, `fraction` the part of the whole work
done so far, in [0, 1], or None when the computation cannot tell.  The
default is `silent`.  Displays for a terminal (all on stderr, all removed
when the block ends):

* `rich_progress`: a progress bar with the message and the elapsed time
  (pulsing while the fraction is unknown);
* `status_line`: one line of text, ``description: message (NN%)``, beside a
  spinner;
* `stderr_progress`: either of them when stderr is a terminal, else
  `silent` (what the command line uses: nothing is written into a log or a
  pipe).
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

__all__ = ["Progress", "silent", "rich_progress", "status_line", "stderr_progress", "progress_text"]

Progress = Callable[[str, float | None], None]
"""``progress(message, fraction)``: what is being done, and the fraction done (or None)."""


def silent(message: str, fraction: float | None = None) -> None:
    """The default `Progress`: ignores every report."""


def progress_text(description: str, message: str, fraction: float | None) -> str:
    """``description: message`` followed by `` (NN%)`` when the fraction is known."""
    text = f"{description}: {message}" if message else description
    return text if fraction is None else f"{text} ({100 * fraction:.0f}%)"


@contextlib.contextmanager
def rich_progress(description: str = "working") -> Iterator[Progress]:
    """A rich progress bar on stderr; yields its `Progress` callback.

    The bar shows ``description: message``, the fraction done (pulsing
    until a fraction is reported) and the elapsed time.
    """
    from rich.console import Console
    from rich.progress import BarColumn, Progress as RichProgress, TextColumn, TimeElapsedColumn

    with RichProgress(
        TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=Console(stderr=True), transient=True
    ) as bar:
        task = bar.add_task(description, total=None)

        def update(message: str, fraction: float | None = None) -> None:
            text = progress_text(description, message, None)
            if fraction is None:
                bar.update(task, description=text)
            else:
                bar.update(task, description=text, total=1.0, completed=fraction)

        yield update


@contextlib.contextmanager
def status_line(description: str = "working") -> Iterator[Progress]:
    """One line of text on stderr, `progress_text` beside a spinner; yields its `Progress` callback."""
    from rich.console import Console

    with Console(stderr=True).status(description) as status:
        yield lambda message, fraction=None: status.update(progress_text(description, message, fraction))


@contextlib.contextmanager
def stderr_progress(description: str = "working", *, bar: bool = False) -> Iterator[Progress]:
    """`rich_progress` (``bar=True``) or `status_line` when stderr is a terminal, else `silent`."""
    from rich.console import Console

    if not Console(stderr=True).is_terminal:
        yield silent
        return
    with (rich_progress if bar else status_line)(description) as progress:
        yield progress
