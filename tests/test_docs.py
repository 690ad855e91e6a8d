"""The repository stands alone: every file a docstring, a comment or a document names exists in it,
and nothing points outside it."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_SKIP = {".git", ".venv", "build", "dist", "__pycache__", ".pytest_cache", ".ruff_cache", ".mypy_cache",
         # the last four: the docs' build
         "piezopreload-out", "_build", "auto_examples", "generated", "jupyter_execute"}
_SUFFIXES = (".py", ".md", ".toml", ".typ", ".txt", ".cfg")
#: a file name with one of these extensions, possibly with folders before it
#: a web address: the files it names are another site's
_URL = re.compile(r"https?://\S+")
_REFERENCE = re.compile(r"(?<![\w.@/-])((?:\.\./)*(?:[\w.-]+/)*[\w.-]+\.(?:md|py|toml|typ|csv))\b")


def _texts() -> list[tuple[Path, str]]:
    out = []
    for path in sorted(ROOT.rglob("*")):
        rel = path.relative_to(ROOT)
        if any(part in _SKIP or part.endswith(".egg-info") for part in rel.parts) or not path.is_file():
            continue
        if path.suffix in _SUFFIXES or path.name in ("LICENSE",):
            out.append((rel, path.read_text(encoding="utf-8", errors="replace")))
    return out


def _folders() -> set[str]:
    return {p.name for p in ROOT.iterdir() if p.is_dir() and p.name not in _SKIP and not p.name.endswith(".egg-info")}


def missing_references(texts: list[tuple[Path, str]]) -> list[str]:
    """``file:line: reference`` for every reference to a file of the repository that does not exist.

    A reference with folders is checked when its first folder is one of the repository's
    (``models/ballscrew.py``, ``docs/models.md``); a bare Markdown name (``paper2021.md``) must
    name a file somewhere in the repository. Anything starting with ``../`` is outside it; a web
    address is skipped whole. A reference starting with ``../`` is resolved from its file's folder:
    inside the repository it must exist, outside it is an error.
    """
    folders, names = _folders(), {p.name for p, _ in texts}
    bad = []
    for rel, text in texts:
        for no, line in enumerate(text.splitlines(), start=1):
            for ref in _REFERENCE.findall(_URL.sub("", line)):
                parts = ref.split("/")
                if parts[0] == "..":
                    target = (ROOT / rel.parent / ref).resolve()
                    ok = target.is_relative_to(ROOT) and target.exists()
                elif len(parts) > 1 and parts[0] in folders:
                    ok = (ROOT / ref).exists()
                elif len(parts) == 1 and ref.endswith(".md"):
                    ok = ref in names
                else:
                    continue  # an output file's name (gains.json, run.csv) or another project's path
                if not ok:
                    bad.append(f"{rel}:{no}: {ref}")
    return bad


def test_every_file_named_in_the_repository_exists():
    bad = missing_references(_texts())
    assert not bad, "references to files the repository does not hold:\n" + "\n".join(bad)


def test_nothing_points_outside_the_repository():
    outside = (".." + "/shared", "/" + "work/")  # spelled apart so this file does not name them
    bad = [f"{rel}:{no}" for rel, text in _texts() for no, line in enumerate(text.splitlines(), start=1)
           if any(o in line for o in outside)]
    assert not bad, "paths outside the repository:\n" + "\n".join(bad)


def test_the_check_catches_a_missing_file():
    """The checker itself: a made-up reference of each kind is reported, a real one is not."""
    md = ".md"  # spelled apart so this file does not name them itself
    texts = [(Path("x.py"), f'"""See ``docs/nowhere{md}``, ``GONE{md}`` and ``../other/file{md}``; '
                            f'also ``docs/models{md}`` and ``gains.json``."""')]
    found = [b for b in missing_references(texts + _texts()) if b.startswith("x.py")]
    assert found == [f"x.py:1: docs/nowhere{md}", f"x.py:1: GONE{md}", f"x.py:1: ../other/file{md}"]


#: the seed paper's authors as its own citation gives them (Appl. Sci. 11, 8491): Guangcheng Zhang, Hao Jin,
#: Yueh-Jaw Lin
_AUTHORS = {"Zhang": ("G.", "Guangcheng"), "Jin": ("H.", "Hao"), "Lin": ("Y.-J.", "Yueh-Jaw")}
_NAMED = re.compile(r"\b((?:[A-Z]\.-?)+|[A-Z][a-z]+(?:-[A-Z][a-z]+)?) (Zhang|Jin|Lin)\b")


def test_the_seed_paper_s_authors_are_named_as_the_paper_names_them():
    """Wherever a document gives the authors' initials or first names, they are the paper's own; the
    references page cites all three."""
    wrong = []
    for rel, text in _texts():
        for n, line in enumerate(text.splitlines(), 1):
            for m in _NAMED.finditer(line):
                given, surname = m.group(1), m.group(2)
                first = given.split()[-1]
                if (given.endswith(".") or first in {"Guangcheng", "Hao", "Yueh-Jaw"}) and \
                        first not in _AUTHORS[surname]:
                    wrong.append(f"{rel}:{n}: {m.group(0)}")
    assert not wrong, "the seed paper's authors named wrongly:\n" + "\n".join(wrong)
    references = (ROOT / "docs" / "references.md").read_text(encoding="utf-8")
    assert "G. Zhang, H. Jin, Y.-J. Lin" in references, "docs/references.md does not cite the paper's authors"
