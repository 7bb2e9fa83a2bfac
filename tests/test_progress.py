"""The one progress protocol (`fitter.progress`): progress(message, fraction or None)."""

import io
import re

from rich.console import Console

from fitter.progress import progress_text, rich_progress, silent, status_line, stderr_progress


def test_text_and_silent_default():
    assert progress_text("fit", "refining", None) == "fit: refining"
    assert progress_text("diagnosing", "testing creep", 0.426) == "diagnosing: testing creep (43%)"
    assert progress_text("fit", "", 1.0) == "fit (100%)"
    assert silent("anything") is None and silent("anything", 0.5) is None


def test_stderr_progress_is_silent_without_a_terminal(capsys):
    for bar in (False, True):
        with stderr_progress("work", bar=bar) as progress:
            assert progress is silent
            progress("step", 0.5)
    assert capsys.readouterr() == ("", "")


def shown(display, monkeypatch) -> str:
    """What `display("work")` writes to a 100-column terminal for three reports."""
    out = io.StringIO()
    monkeypatch.setattr(
        "rich.console.Console", lambda stderr=True: Console(file=out, force_terminal=True, color_system=None, width=100)
    )
    with display("work") as progress:
        progress("first step")
        progress("second step", None)
        progress("third step", 0.75)
    return out.getvalue()


def test_status_line_shows_message_and_percentage(monkeypatch):
    assert "work: third step (75%)" in shown(status_line, monkeypatch)


def test_rich_progress_bar_fills_to_the_fraction(monkeypatch):
    last = re.search(r"work: third step (━+) +0:00", shown(rich_progress, monkeypatch))
    assert len(last.group(1)) == 30  # 75% of the 40-column bar
