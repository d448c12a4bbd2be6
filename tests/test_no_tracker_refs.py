"""No tracker or work-period numbers and no commit hashes in the code, tests, benchmarks or docs.

A comment says its reason itself, or cites a ``docs/design.md`` section by its title; a
number of a tracker entry or of a work period, or a commit hash, means nothing to a reader
who has neither at hand.
"""

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SELF = Path(__file__).resolve()

#: a work period or tracker entry named by its number ("Issues" and plural forms too).
NUMBERED = re.compile(r"(?i)\b(session|sessions|issue|issues) [0-9]+")
#: A commit hash (7-40 hex digits, with at least one digit and one letter) after a word that
#: names a revision: "commit 1a2b3c4", "at 1a2b3c4", "a worktree of 1a2b3c4", "before (1a2b3c4)".
HASH = re.compile(r"(?i)\b(commit|commits|at|of|before|after)\b[\s=:(`]*"
                  r"(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
#: Leading comment or docstring markup of a continuation line (a reference broken over two
#: lines, "docs/design.md, session\n#: 16", is joined before the search).
_CONTINUATION = re.compile(r"^\s*(#:?|//|\*|>)?\s*")
SUFFIXES = {".py", ".md", ".sh", ".toml", ".txt", ".cfg", ".ini", ".yml", ".yaml", ".json"}


def tracker_refs(text: str) -> list:
    """(line number, line) of each line of ``text`` with a tracker, work-period or commit
    reference, alone or continued on the next line."""
    lines = text.splitlines()
    bad = []
    for i, line in enumerate(lines):
        head = line.rstrip()
        nxt = _CONTINUATION.sub("", lines[i + 1]) if i + 1 < len(lines) else ""
        joined = f"{head} {nxt}"
        # On the joined pair, only a match that starts on this line (the next line's own
        # matches are its own).
        if any(p.search(line) or any(m.start() < len(head) for m in p.finditer(joined))
               for p in (NUMBERED, HASH)):
            bad.append((i + 1, line.strip()))
    return bad


def _files(paths):
    for top in paths:
        top = ROOT / top
        if top.is_file():
            yield top
            continue
        # os.walk does not follow links: jaxgrasp/assets (a link to ../assets) is data.
        for folder, dirs, names in os.walk(top):
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "__pycache__")
            for name in sorted(names):
                path = Path(folder) / name
                if path.suffix in SUFFIXES and path.resolve() != SELF:
                    yield path


def scan(paths) -> list:
    """``file:line: text`` of every tracker, work-period or commit reference under ``paths``
    (relative to the repository root)."""
    out = []
    for path in _files(paths):
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        rel = path.relative_to(ROOT)
        out += [f"{rel}:{n}: {line}" for n, line in tracker_refs(text)]
    return out


def test_scanner_flags_references():
    # The examples are split so that this file itself holds no reference.
    ref = "see sess" "ion 12"
    assert tracker_refs(ref) == [(1, ref)]
    assert [n for n, _ in tracker_refs("a\n(Iss" "ue 5: agreement)\nb")] == [2]
    assert tracker_refs("measured at commit 1a2b3c4 on a 2-core machine")
    assert tracker_refs("before = a worktree of 24346cc")
    # A reference broken over two comment lines is found on its first line.
    assert [n for n, _ in tracker_refs("x = 1\n#: docs/design.md, session\n#: 16).")] == [2]
    # Not references: a pytest fixture scope, plain numbers, words made of hex letters.
    assert tracker_refs('@pytest.fixture(scope="session")\nat 1000000 trials\nat deadbeefed') == []
    assert tracker_refs('docs/design.md, "A deadlock in the batched epsilon"') == []


def test_code_has_no_tracker_refs():
    bad = scan(["jaxgrasp", "tests", "benchmarks"])
    assert not bad, ("say the reason, or cite a docs/design.md section by its title, not a "
                     "tracker or work-period number or a commit hash:\n" + "\n".join(bad))


def test_docs_have_no_tracker_refs():
    bad = scan(["docs", "README.md", "assets"])
    assert not bad, ("say the reason, or cite a docs/design.md section by its title, not a "
                     "tracker or work-period number or a commit hash:\n" + "\n".join(bad))


#: ``docs/design.md, "Title"`` (the title may run onto the next comment line).
CITATION = re.compile(r'docs/design\.md(?:``)?,\s*"([^"]+)"')


def cited_sections(text: str) -> list:
    """Titles of the docs/design.md sections ``text`` cites, comment markup removed."""
    flat = " ".join(_CONTINUATION.sub("", line) for line in text.splitlines())
    return [" ".join(t.split()) for t in CITATION.findall(flat)]


def design_headings() -> set:
    text = (ROOT / "docs" / "design.md").read_text()
    return {line.lstrip("#").strip() for line in text.splitlines() if line.startswith("#")}


def test_citation_reader_finds_titles():
    assert cited_sections('x  # (docs/design.md, "The JAX\n    # tail: contacts")') == [
        "The JAX tail: contacts"]
    assert "Scaling" in design_headings()  # the companion: a real heading is found ...
    assert "Concurrent bench cells" not in design_headings()  # ... and a gone one is not


def test_cited_design_sections_exist():
    headings = design_headings()
    bad = [f"{path.relative_to(ROOT)}: {title!r}"
           for path in _files(["jaxgrasp", "tests", "benchmarks", "README.md", "docs"])
           if path.suffix in (".py", ".md", ".sh")
           for title in cited_sections(path.read_text()) if title not in headings]
    assert not bad, "cited docs/design.md sections that do not exist:\n" + "\n".join(bad)
