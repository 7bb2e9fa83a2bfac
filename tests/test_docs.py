"""The README is a quickstart and the docs hold together: README.md at most 150 lines, opening with the two
commands; every relative link in README.md and docs/*.md points at an existing file (and, into a Markdown file, at
an existing heading)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))

OPENING = """```sh
make demo    # fresh venv + install; fit examples/demo.csv, export an FMU, validate it with fmpy, diagnose examples/diagnose/
make test    # fresh venv + install; the test suite but its 8 longest tests (pytest-xdist, two workers; make test-slow: those)
```"""

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _links(text: str) -> list[str]:
    return LINK.findall(FENCE.sub("", text))


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation other than '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text())
    return {_anchor(m) for m in re.findall(r"^#{1,6}\s+(.*)$", text, re.M)}


def test_readme_is_at_most_150_lines():
    lines = README.read_text().splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines (at most 150: details go to docs/)"


def test_readme_opens_with_the_two_commands():
    text = README.read_text()
    first_block = text[text.index("```") :]
    assert first_block.startswith(OPENING), "README.md must open with the make demo / make test block"
    before = text[: text.index("```")].strip().splitlines()
    assert len(before) == 1 and before[0].startswith("# "), "only the title may come before the two commands"


def test_readme_links_the_docs():
    links = set(_links(README.read_text()))
    for name in ("docs/user-guide.md", "docs/results.md", "docs/fmu.md", "docs/architecture.md"):
        assert name in links, f"README.md does not link {name}"


@pytest.mark.parametrize("path", [README, *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_existing_files_and_headings(path):
    broken = []
    for link in _links(path.read_text()):
        if re.match(r"^[a-z][a-z0-9+.-]*:", link):  # http:, https:, mailto:
            continue
        target, _, fragment = link.partition("#")
        file = (path.parent / target).resolve() if target else path
        if not file.exists():
            broken.append(f"{link}: no file {file.relative_to(ROOT) if file.is_relative_to(ROOT) else file}")
        elif fragment and file.suffix == ".md" and fragment not in _anchors(file):
            broken.append(f"{link}: no heading #{fragment} in {file.relative_to(ROOT)}")
    assert not broken, f"{path.relative_to(ROOT)}: " + "; ".join(broken)
