"""The README's commands that code runs exist once (``mavastsm.readme_commands``) and match README.md line for line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mavastsm.readme_commands import README_COMMANDS, readme_argv

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_command_lines(text: str) -> list[str]:
    """Every line of the README's ```bash blocks, its trailing ``# comment`` and spaces cut."""
    lines = []
    for block in re.findall(r"^```bash\n(.*?)^```", text, re.MULTILINE | re.DOTALL):
        for line in block.splitlines():
            command = re.sub(r"\s+#.*$", "", line).strip()
            if command and not command.startswith("#"):
                lines.append(command)
    return lines


@pytest.mark.parametrize("name", sorted(README_COMMANDS))
def test_each_command_in_code_is_a_command_line_of_the_readme(name):
    lines = readme_command_lines(README.read_text(encoding="utf-8"))
    assert README_COMMANDS[name] in lines, f"README_COMMANDS[{name!r}] is not in README.md: {README_COMMANDS[name]!r}"


def test_a_changed_readme_command_is_caught():
    text = README.read_text(encoding="utf-8").replace("--takeoff 5 --on-exit LAND", "--takeoff 4 --on-exit LAND")
    assert README_COMMANDS["px4"] not in readme_command_lines(text)
    assert README_COMMANDS["arducopter"] in readme_command_lines(text)


@pytest.mark.parametrize("name", [n for n in sorted(README_COMMANDS) if README_COMMANDS[n].startswith("mavastsm ")])
def test_readme_argv_is_what_follows_mavastsm(name):
    assert " ".join(["mavastsm", *readme_argv(name)]) == README_COMMANDS[name]


def test_readme_argv_refuses_a_command_that_is_not_mavastsm():
    with pytest.raises(ValueError, match="not a mavastsm command"):
        readme_argv("test_suite")
