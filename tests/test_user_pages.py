"""The user-facing pages (README.md and the manual's sources, docs/**/*.md) state what is current:
no commit hash (a 7-40 character hex word that is an object of this repository) and no words of
a lab notebook ("previous session", "before this change", an issue number). History belongs in
CHANGELOG.md, which docs/changelog.md includes and these checks leave out. The README also stays
a short start page whose links lead somewhere.

The built site gets the same words checked in tests/test_docs.py; these tests read the sources,
so they need no Sphinx, and they ask git which hex words really are objects.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Pages of history, allowed to name versions and changes.
HISTORY_PAGES = {ROOT / "docs" / "changelog.md"}
#: Words of a lab notebook. "issue N" is how the project's history names its changes.
HISTORY_WORDS = re.compile(
    r"previous session|this session|earlier session|before this change|this branch"
    r"|\bat commit\b|\bthe base commit\b|\bissue[ -]\d+",
    re.I,
)
#: A word that could be an abbreviated or full object name.
HEX_WORD = re.compile(r"(?<![\w.-])[0-9a-f]{7,40}(?![\w-])")
#: Without git: a hex word with a letter and a digit is taken for a hash.
HASH_LIKE = re.compile(r"(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}")
README_MAX_LINES = 150


def user_pages() -> list[Path]:
    """README.md and every Markdown source of the manual but the changelog and the build."""
    pages = [ROOT / "README.md"]
    for page in sorted((ROOT / "docs").rglob("*.md")):
        if "_build" in page.parts or page in HISTORY_PAGES:
            continue
        pages.append(page)
    return pages


def _git_objects(words: set[str]) -> set[str] | None:
    """The words that name an object of this repository (None: git or the repository missing)."""
    git = shutil.which("git")
    if git is None or not (ROOT / ".git").exists():
        return None
    ordered = sorted(words)
    done = subprocess.run(
        [git, "cat-file", "--batch-check"],
        input="".join(f"{w}\n" for w in ordered),
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
    )
    found = set()
    for word, line in zip(ordered, done.stdout.splitlines(), strict=True):
        # "<sha> <type> <size>" for an object; "<word> missing" or "<word> ambiguous" otherwise
        if not line.endswith((" missing", " ambiguous")):
            found.add(word)
    return found


def find_history(text: str, objects: set[str] | None) -> list[str]:
    """The history words and commit hashes of one page's text.

    ``objects`` is the set of hex words of the text that are git objects, or None to take every
    hex word with a letter and a digit for a hash.
    """
    found = [m.group(0) for m in HISTORY_WORDS.finditer(text)]
    for match in HEX_WORD.finditer(text):
        word = match.group(0)
        is_hash = word in objects if objects is not None else bool(HASH_LIKE.fullmatch(word))
        if is_hash:
            found.append(word)
    return found


def _findings(pages: list[Path]) -> list[str]:
    texts = {page: page.read_text(encoding="utf-8") for page in pages}
    words = {m.group(0) for text in texts.values() for m in HEX_WORD.finditer(text)}
    objects = _git_objects(words)
    return [
        f"{page.relative_to(ROOT) if page.is_relative_to(ROOT) else page}: {word!r}"
        for page, text in texts.items()
        for word in find_history(text, objects)
    ]


def test_no_user_page_carries_a_commit_hash_or_history_words() -> None:
    pages = user_pages()
    assert len(pages) > 20, pages  # the README and the manual's pages were found
    found = _findings(pages)
    assert not found, "history belongs in CHANGELOG.md:\n" + "\n".join(found[:40])


def test_the_check_finds_a_real_commit_hash_and_notebook_words(tmp_path: Path) -> None:
    """The check itself: a page with this repository's HEAD and a lab-notebook sentence fails."""
    git = shutil.which("git")
    if git is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    head = subprocess.run(
        [git, "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT, check=True
    ).stdout.strip()
    page = tmp_path / "page.md"
    page.write_text(
        f"Measured at {head[:7]} in the previous session (issue 23); the full id is {head}.\n"
        "Its tolerance is 1e-10 and a hex word that is no object, abcdef0123, is kept.\n",
        encoding="utf-8",
    )
    found = _findings([page])
    words = [f.split(": ", 1)[1] for f in found]
    assert words == ["'previous session'", "'issue 23'", repr(head[:7]), repr(head)], found


def test_the_readme_is_a_short_start_page_whose_links_resolve() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"
    for command in ("make demo", "make test"):
        assert command in text
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not re.match(r"[a-z]+://", t)]
    assert local, "the README links into the manual"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, f"README.md links to missing files: {missing}"
