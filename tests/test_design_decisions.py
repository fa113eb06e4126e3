"""The repository cites only documents it contains: no file cites the outside research notes, and every
citation of docs/design-decisions.md (the page, a comma, then an ID ``CTL-n`` or ``MAV-n``) names an entry
that exists on that page."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "design-decisions.md"
SCANNED = ["mavastsm", "sim", "configs", "docs", "tests", "benchmarks", "README.md"]
# Built from pieces so that this file does not match itself.
OUTSIDE = ["control" + "-notes", "mavlink" + "-notes", "astsm-paper" + ".md", "../shared" + "/reference"]
BINARY = {".png", ".svg", ".pyc", ".gz", ".npz", ".csv", ".tlog"}
ID = re.compile(r"\b((?:CTL|MAV)-\d+)\b")


def _files():
    for name in SCANNED:
        top = ROOT / name
        paths = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file())
        for path in paths:
            if path.suffix in BINARY or "__pycache__" in path.parts:
                continue
            yield path, path.read_text(encoding="utf-8", errors="replace")


def _defined_ids() -> set[str]:
    return set(re.findall(r"^### ((?:CTL|MAV)-\d+):", PAGE.read_text(encoding="utf-8"), flags=re.M))


def test_no_file_cites_a_document_outside_the_repository():
    hits = [f"{path.relative_to(ROOT)}:{n}: {word}"
            for path, text in _files()
            for n, line in enumerate(text.splitlines(), 1)
            for word in OUTSIDE if word in line]
    assert not hits, "cite docs/design-decisions.md instead of outside documents:\n" + "\n".join(hits)


def test_every_design_decision_citation_names_an_entry_on_the_page():
    defined = _defined_ids()
    assert {"CTL-1", "CTL-14", "MAV-1", "MAV-13"} <= defined
    missing = sorted({f"{path.relative_to(ROOT)}: {ident}"
                      for path, text in _files() for ident in ID.findall(text) if ident not in defined})
    assert not missing, "citations of IDs that docs/design-decisions.md does not define:\n" + "\n".join(missing)


def test_every_citation_of_the_page_names_an_entry():
    bare = [f"{path.relative_to(ROOT)}:{n}"
            for path, text in _files()
            for n, line in enumerate(text.splitlines(), 1)
            for m in re.finditer(r"design-decisions\.md,", line)
            if not ID.match(line[m.end():].lstrip())]
    assert not bare, "a citation of docs/design-decisions.md needs an ID (CTL-n or MAV-n) after the comma:\n" + "\n".join(bare)


def test_the_page_defines_each_id_once():
    ids = re.findall(r"^### ((?:CTL|MAV)-\d+):", PAGE.read_text(encoding="utf-8"), flags=re.M)
    assert len(ids) == len(set(ids))
