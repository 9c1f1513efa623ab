"""Every document the code cites is in the repository, and so is every label and section it names;
every module and file the documents name exists.

The code cites the project's own ``docs/`` (``docs/method.md (M3)``, ``docs/method.md, "Evaluation
protocols"``), never a file outside the repository, and carries no issue numbers: a reader must be
able to follow every citation from a fresh clone.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CODE_DIRS = ("core", "hardware", "app", "bench", "frontend/js", "scripts", "examples", "tests")
SUFFIXES = (".py", ".js", ".sh")

DOC_PATH = re.compile(r"docs/([\w./-]+\.(?:md|png|toml|json))")
LABEL = re.compile(r"docs/method\.md[^\n]{0,40}?\((M\d+)\)")
SECTION = re.compile(r'docs/([\w-]+\.md),?\s+"([^"]+)"')
OUTSIDE = re.compile(r"\b(METHOD|DESIGN|CONVENTIONS)\.md\b")
ISSUE_NUMBER = re.compile(r"\b[Ii]ssues? ?#?\d+\b")


def _code_files() -> list[Path]:
    files: list[Path] = []
    for folder in CODE_DIRS:
        base = ROOT / folder
        if base.exists():
            files += [
                p
                for p in sorted(base.rglob("*"))
                if p.suffix in SUFFIXES and not {"node_modules", "vendor"} & set(p.parts)
            ]
    return files


def _headings(doc: Path) -> str:
    return "\n".join(line for line in doc.read_text().splitlines() if line.startswith("#"))


FILES = _code_files()


def test_the_scan_sees_the_code() -> None:
    names = {p.relative_to(ROOT).as_posix() for p in FILES}
    assert "core/recognition/session.py" in names
    assert any(n.startswith("frontend/js/") for n in names)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_citations_resolve(path: Path) -> None:
    if path.name == "test_citations.py":
        return
    text = path.read_text(encoding="utf-8")
    problems = []
    for match in DOC_PATH.finditer(text):
        if not (ROOT / "docs" / match.group(1)).exists():
            problems.append(f"docs/{match.group(1)} does not exist")
    method = (ROOT / "docs" / "method.md").read_text()
    for match in LABEL.finditer(text):
        if f"({match.group(1)})" not in method:
            problems.append(f"label ({match.group(1)}) is not in docs/method.md")
    for match in SECTION.finditer(text):
        doc = ROOT / "docs" / match.group(1)
        # A section name may run over a line break of a comment (``#``, ``#:``, ``//``).
        section = " ".join(re.sub(r"\n\s*(#:?|//|\*)?", " ", match.group(2)).split())
        if doc.exists() and section.split(":")[0] not in " ".join(_headings(doc).split()):
            problems.append(f'docs/{match.group(1)} has no section "{section}"')
    for match in OUTSIDE.finditer(text):
        problems.append(f"cites {match.group(0)}, which is not in the repository")
    for match in ISSUE_NUMBER.finditer(text):
        problems.append(f"carries an issue number ({match.group(0)!r})")
    assert not problems, "; ".join(problems)


DOCS = [*sorted((ROOT / "docs").rglob("*.md")), ROOT / "README.md"]
MODULE = re.compile(r"(?<![\w/.\-])((?:core|app|hardware|bench)(?:\.[A-Za-z_]\w*)+)")
REPO_PATH = re.compile(
    r"(?<![\w/.])((?:core|app|hardware|bench|tests|frontend|scripts|migrations)/[\w/.-]*\w)"
)


def _module_resolves(dotted: str) -> bool:
    """Whether ``dotted`` starts with a module of ours (``core.gp.posterior.condition``)."""
    parts = dotted.split(".")
    for k in range(len(parts), 1, -1):
        base = ROOT.joinpath(*parts[:k])
        if base.with_suffix(".py").is_file() or (base / "__init__.py").is_file():
            return True
    return False


def _path_resolves(path: str) -> bool:
    """Whether ``path`` is a file or folder of the repository (``core/gp/posterior.py``), also
    when cited with a name in it (``core/gp/posterior.predict``)."""
    stem = re.sub(r"\.\w+$", "", path)
    return any((ROOT / p).exists() for p in (path, f"{path}.py", stem, f"{stem}.py"))


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_modules_and_paths_the_docs_name_exist(doc: Path) -> None:
    text = doc.read_text(encoding="utf-8")
    missing = [m.group(1) for m in MODULE.finditer(text) if not _module_resolves(m.group(1))]
    missing += [m.group(1) for m in REPO_PATH.finditer(text) if not _path_resolves(m.group(1))]
    assert not missing, f"{doc.name} names what is not in the repository: {sorted(set(missing))}"
