"""The docs stay readable and connected (issue 32, "Docs for users").

Each user doc (docs/*.md) says what a user does and what the result means, so it stays short
(experiments go to dated docs/notes/ files, which have no limit); and every relative link in docs/
and README.md leads to a file that exists, so moving text into a note cannot strand a reader.
"""
from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: "at most about 350 lines" (the issue); the test allows a few lines of slack for a merge
MAX_USER_DOC_LINES = 360

#: [text](target) and ![alt](target), without the optional "title"; nested brackets in the text are rare
LINK = re.compile(r"!?\[[^\]\n]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
#: fenced code blocks and inline code spans hold examples, not links
FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
CODE_SPAN = re.compile(r"`[^`\n]*`")
EXTERNAL = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)  # http:, https:, mailto:, ...

USER_DOCS = sorted(DOCS.glob("*.md"))
LINKED_FILES = sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]


def relative_links(text: str) -> list[str]:
    """The link targets of a Markdown text that name a file of the repository (no URL, no bare anchor)."""
    prose = CODE_SPAN.sub("", FENCE.sub("", text))
    targets = []
    for target in LINK.findall(prose):
        if EXTERNAL.match(target) or target.startswith("#"):
            continue
        targets.append(target)
    return targets


def resolves(source: Path, target: str) -> bool:
    path = unquote(target.split("#", 1)[0].split("?", 1)[0])
    if not path:
        return True
    base = ROOT if path.startswith("/") else source.parent
    return (base / path.lstrip("/")).resolve().exists()


def test_there_are_user_docs_and_notes():
    assert len(USER_DOCS) >= 10, USER_DOCS
    assert any((DOCS / "notes").glob("*.md")), "experiments live in docs/notes/"


@pytest.mark.parametrize("doc", USER_DOCS, ids=lambda p: p.name)
def test_a_user_doc_is_short(doc: Path):
    lines = doc.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_USER_DOC_LINES, (
        f"{doc.relative_to(ROOT)} has {lines} lines (> {MAX_USER_DOC_LINES}): move experiments and their "
        "figures to a dated docs/notes/YYYY-MM-DD-<topic>.md and link it")


def test_notes_are_dated():
    for note in (DOCS / "notes").glob("*.md"):
        assert re.match(r"\d{4}-\d{2}-\d{2}-[a-z0-9][a-z0-9-]*\.md$", note.name), note.name


@pytest.mark.parametrize("source", LINKED_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(source: Path):
    broken = [t for t in relative_links(source.read_text(encoding="utf-8")) if not resolves(source, t)]
    assert not broken, f"{source.relative_to(ROOT)}: links to missing files: {broken}"


def test_the_link_check_finds_a_broken_link(tmp_path: Path):
    doc = tmp_path / "a.md"
    doc.write_text("see [b](b.md), [c](sub/c.md#part), [web](https://example.org), [here](#top), `[x](x.md)`\n"
                   "```\n[y](y.md)\n```\n")
    (tmp_path / "b.md").write_text("")
    assert relative_links(doc.read_text()) == ["b.md", "sub/c.md#part"]
    assert resolves(doc, "b.md") and not resolves(doc, "sub/c.md#part")


# --- what the docs name exists (issue 32, "nothing in the user docs is false") --------------------

#: a package's user doc and the package its module table lists (``| `x.py` | ...`` rows)
MODULE_TABLES = {"fitting.md": "fitting", "service.md": "service", "planning.md": "planning",
                 "mavlink.md": "mavlink", "sim.md": "sim", "packs.md": "packs", "model.md": "models",
                 "vehicles.md": "vehicle", "estimation.md": "estimation"}
MODULE_ROW = re.compile(r"^\| `([\w./]+\.py)` \|", re.M)


def missing_modules(text: str, package: Path) -> list[str]:
    """The ``x.py`` a module table names that neither ``package`` nor the repository holds."""
    return [f for f in MODULE_ROW.findall(text)
            if not (package / f).resolve().is_file() and not (package.parent / f).is_file() and not (ROOT / f).is_file()]


@pytest.mark.parametrize("doc", sorted(MODULE_TABLES))
def test_a_module_table_names_files_that_exist(doc: str):
    package = ROOT / "gcs_pdm" / MODULE_TABLES[doc]
    assert package.is_dir(), package
    missing = missing_modules((DOCS / doc).read_text(encoding="utf-8"), package)
    assert not missing, f"docs/{doc} lists modules gcs_pdm/{MODULE_TABLES[doc]} does not have: {missing}"


def test_the_module_check_finds_a_moved_module():
    text = "| `logs.py` | shell | ... |\n| `../logs/tables.py` | core | ... |\n| `tables.py` | core | ... |\n"
    assert missing_modules(text, ROOT / "gcs_pdm" / "fitting") == ["tables.py"]


def test_the_configuration_table_is_the_service_config():
    """docs/configuration.md names every ServiceConfig key once, none that is not one, and each plain
    default (a number, true/false, none) as the code has it."""
    from gcs_pdm.service.config import ServiceConfig

    rows = re.findall(r"^\| (`\w+`(?: / `\w+`)*) \| ([^|]+) \|", (DOCS / "configuration.md").read_text(encoding="utf-8"),
                      re.M)
    documented = {}
    for keys, defaults in rows:
        names, values = re.findall(r"`(\w+)`", keys), [d.strip() for d in defaults.split(" / ")]
        documented.update({n: values[i] if len(values) == len(names) else None for i, n in enumerate(names)})
    fields = ServiceConfig.model_fields
    assert set(documented) == set(fields), (sorted(set(documented) - set(fields)), sorted(set(fields) - set(documented)))
    plain = {"true": True, "false": False, "none": None}
    for name, text in documented.items():
        if text is None or not re.fullmatch(r"-?[\d.]+|true|false|none", text):
            continue  # a default written in words ("generated, logged", "256 MiB") is read by a person
        want = plain[text] if text in plain else float(text)
        assert fields[name].default == want, f"configuration.md: {name} defaults to {text}, the code to {fields[name].default!r}"
