"""docs/security.md points at the tests that measure each of its claims: every test it names must exist (so the
page cannot cite a test that was renamed or removed), and every hostile-traffic test must be cited by it."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "security.md").read_text(encoding="utf-8")


def _defined_tests() -> set[str]:
    names = set()
    for path in (ROOT / "tests").rglob("test_*.py"):
        names.update(re.findall(r"^def (test_\w+)", path.read_text(encoding="utf-8"), flags=re.M))
    return names


def test_every_test_the_security_page_names_exists():
    cited = set(re.findall(r"\b(test_\w+)\b(?!\.py)", DOC))  # test functions; files are cited with their .py
    missing = cited - _defined_tests()
    assert not missing, f"docs/security.md names tests that do not exist: {sorted(missing)}"


def test_every_hostile_traffic_and_signing_test_is_on_the_security_page():
    files = [ROOT / "tests" / "bridge" / "test_hostile_traffic.py", ROOT / "tests" / "sim" / "test_hostile_peers.py"]
    tests = {name for f in files for name in re.findall(r"^def (test_\w+)", f.read_text(encoding="utf-8"), flags=re.M)}
    tests.update({"test_a_forged_frame_does_not_cut_a_signed_stream", "test_our_signing_timestamp_never_lags_the_clock",
                  "test_replay_across_a_restart"})
    absent = {t for t in tests if t not in DOC}
    assert not absent, f"tests not cited in docs/security.md: {sorted(absent)}"
    assert "SOAK_RESULT" not in DOC, "the soak result placeholder was never filled in"
