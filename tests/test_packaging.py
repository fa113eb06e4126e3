"""Packaging: configs ship inside the package, the CI script runs the README test command, and the
CLI turns bad input into a one-line error with exit status 2."""

from __future__ import annotations

import argparse
import fnmatch
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the test extra installs tomli there
    import tomli as tomllib

from mavastsm import cli
from mavastsm.config_loading import read_yaml, resolve_config
from mavastsm.readme_commands import README_COMMANDS

ROOT = Path(__file__).resolve().parents[1]
README_TEST_COMMAND = README_COMMANDS["test_suite"]  # held to README.md by tests/test_readme_commands.py


def test_configs_resolvable_through_the_package():
    base = resources.files("mavastsm.configs")
    for rel in ("vehicle/solo.yaml", "controllers/astsm.yaml", "controllers/astsm_paper.yaml", "scenarios/nominal.yaml",
                "scenarios/disturbance.yaml", "scenarios/variation.yaml", "references/paper_steps.yaml"):
        assert base.joinpath(rel).is_file(), rel
    for folder in ("vehicle", "controllers", "scenarios", "references"):
        for p in Path(str(base / folder)).glob("*.yaml"):
            assert isinstance(read_yaml(p), dict)
            assert resolve_config(p.stem, folder) == p


def test_pyproject_ships_every_config_and_subpackage():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = meta["package-data"]["mavastsm.configs"]
    for f in [*(ROOT / "configs").rglob("*.yaml"), *(ROOT / "configs").rglob("*.parm")]:
        rel = f.relative_to(ROOT / "configs").as_posix()
        assert any(fnmatch.fnmatch(rel, pat) or fnmatch.fnmatch(rel, pat.replace("**/", "")) for pat in patterns), rel
    declared = set(meta["packages"])
    for init in (ROOT / "mavastsm").rglob("__init__.py"):
        pkg = ".".join(init.parent.relative_to(ROOT).parts)
        if "__pycache__" not in pkg:
            assert pkg in declared, f"{pkg} missing from pyproject packages"


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text()
    assert README_TEST_COMMAND in ci
    assert "set -euo pipefail" in ci


def run_cli(argv, capsys):
    rc = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    return rc, [line for line in err if "error" in line]


@pytest.fixture
def bad_files(tmp_path):
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("scenario: [unclosed\n")
    negative = tmp_path / "neg.yaml"
    src = (ROOT / "configs" / "controllers" / "stsm.yaml").read_text()
    negative.write_text(src.replace("value: [35.65, 26.94, 22.07]", "value: [-35.65, 26.94, 22.07]"))
    return {"malformed": malformed, "negative": negative}


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["simulate", "--controller", "lqr"], "unknown controller 'lqr'; registered: astsm"),
        (["simulate", "--scenario", "hurricane"], "hurricane: no such file or packaged config; packaged scenarios:"),
        (["simulate", "--scenario", "/nonexistent/dir/s.yaml"], "s.yaml: no such file"),
        (["simulate", "--scenario", "{malformed}"], "malformed YAML"),
        (["simulate", "--controller", "stsm:{negative}"], "gains.k1' = -35.65 breaks rule: must be >= 0.0"),
        (["simulate", "--set", "mu=-0.5"], "gains.mu' = -0.5 breaks rule: must be > 0.0"),
        (["simulate", "--dt-ms", "0"], "--dt-ms = 0.0 breaks rule: must be a time > 0 ms"),
        (["simulate", "--dt-ms", "-2.5"], "must be a time > 0 ms"),
        (["reproduce", "--modes", "Q"], "unknown mode(s) ['Q']"),
        (["reproduce", "--paper-period-ms", "0"], "must be a time > 0 ms"),
        (["check-config", "nope/nothing"], "no such file"),
    ],
)
def test_bad_input_one_line_error_exit_2(argv, needle, bad_files, capsys):
    argv = [a.format(**bad_files) for a in argv]
    rc, errors = run_cli(argv, capsys)
    assert rc == 2
    assert len(errors) == 1 and errors[0].startswith(f"mavastsm {argv[0]}: error: ")
    assert needle in errors[0]


def test_list_controllers_and_check_config(capsys):
    assert cli.main(["list-controllers"]) == 0
    out = capsys.readouterr().out
    for key in ("astsm", "stsm", "smc", "atsm", "pid", "pid_fair"):
        assert key in out
    for name in ("controllers/astsm_paper", "vehicle/solo", "scenarios/disturbance_pulse", "references/yaw_ramp"):
        assert cli.main(["check-config", name]) == 0
        assert "valid" in capsys.readouterr().out


def test_console_script_exit_status():
    proc = subprocess.run([sys.executable, "-m", "mavastsm.cli", "simulate", "--dt-ms", "-1"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().endswith("--dt-ms = -1.0 breaks rule: must be a time > 0 ms")


def test_configs_found_when_run_from_a_source_checkout():
    """`python -m mavastsm.cli` in the repo root imports the source `mavastsm/` ahead of the installed
    package; that folder has no `configs` subpackage (the configs are the checkout's top-level folder),
    so config lookups must fall back to it. GIVEN the repo root as working directory WHEN a command
    loads packaged configs THEN it works (and a bad name still gives the one-line error, exit 2)."""
    import subprocess
    import sys

    ok = subprocess.run([sys.executable, "-m", "mavastsm.cli", "check-config", "scenarios/nominal"], cwd=ROOT,
                        capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    assert "valid" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "mavastsm.cli", "simulate", "--controller", "astsm", "--scenario", "bogus"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2
    assert "packaged scenarios: " in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.parametrize("argv,command", [
    (["sim", "--listen", "notanaddress"], "sim"),
    (["simulate", "--dt-ms", "abc"], "simulate"),
    (["reproduce", "--workers", "5"], "reproduce"),
    (["demo", "--speedup", "x"], "demo"),
])
def test_every_subcommand_reports_a_bad_option_in_one_line(argv, command, capsys):
    """The ux issue, item 10: `sim --listen notanaddress` printed the option name twice and 11 lines of usage;
    `reproduce --workers 5` silently ran 2 processes. Every subcommand now says it in one line, exit 2."""
    from mavastsm.cli import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"mavastsm {command}: error: argument "), err
    assert err[0].count(argv[1]) == 1 and err[0].endswith(f"(see 'mavastsm {command} --help')"), err


def _options_by_command() -> dict[str, set[str]]:
    from mavastsm.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {name: {s for action in p._actions for s in action.option_strings} for name, p in sub.choices.items()}


def test_the_same_thing_has_the_same_option_name_and_unit_in_every_command():
    """The ux issue, item 10: `demo --takeoff-m` vs `connect --takeoff`, `sim --duration-s` vs `connect --duration`,
    `--out` an address in `sim` but a folder in `reproduce`, `--baud` vs MAVProxy's `--baudrate`. Canonical names
    carry their unit; the README's older spellings stay as aliases."""
    canonical = {"--takeoff": "--takeoff-m", "--duration": "--duration-s", "--rate": "--rate-hz", "--baudrate": "--baud"}
    for command, opts in _options_by_command().items():
        for old, new in canonical.items():
            if old in opts:
                assert new in opts, f"mavastsm {command}: {old} without {new}"
        if "--out" in opts:  # an address everywhere (SITL's and MAVProxy's meaning), never a folder or a file
            assert command in ("sim",) or "--out-dir" in opts, f"mavastsm {command}: --out is not an address here"


def _every_help_text() -> dict[str, str]:
    """`mavastsm --help` and every subcommand's --help, as argparse formats them (wide, so nothing wraps)."""
    import os

    from mavastsm.cli import build_parser

    os.environ["COLUMNS"] = "400"  # argparse reads it when formatting
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        texts = {"mavastsm": parser.format_help()}
        texts.update({f"mavastsm {name}": p.format_help() for name, p in sub.choices.items()})
    finally:
        del os.environ["COLUMNS"]
    return texts


# other spellings of "dimensionless" seen or likely in unit brackets; the project writes [-]
OTHER_DIMENSIONLESS_SPELLINGS = ("[x]", "[×]", "[1]", "[ ]", "[none]", "[dimensionless]", "[unitless]", "[ratio]")


def test_dimensionless_values_are_written_one_way_in_every_help_and_doc():
    """The ux issue, item 10: units were written `[x]` in one place (`sim --speedup`) and `[-]` in another. The
    convention is `[-]` in help and docs, `-` in the unit column of check-config (the configs' own `unit: "-"`)."""
    texts = _every_help_text()
    assert len(texts) > 8 and "[-]" in "".join(texts.values())
    docs = {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]}
    for where, text in {**texts, **docs}.items():
        found = [s for s in OTHER_DIMENSIONLESS_SPELLINGS if s in text]
        assert not found, f"{where}: {found} (write dimensionless values as [-])"
    from mavastsm.config_loading import packaged_config_dir

    units = set()
    for f in sorted(packaged_config_dir().rglob("*.yaml")):
        units |= _units_in(read_yaml(f))
    assert "-" in units and not units & {"x", "×", "1", "", "none", "dimensionless"}, units


def _units_in(node) -> set[str]:
    """Every parameter's ``unit`` in a config tree (the specs check-config prints)."""
    if isinstance(node, dict):
        found = {str(node["unit"])} if "unit" in node and "value" in node else set()
        for value in node.values():
            found |= _units_in(value)
        return found
    if isinstance(node, list):
        return set().union(*(_units_in(v) for v in node)) if node else set()
    return set()


def test_bench_quick_time_is_the_same_figure_in_its_help_and_the_readme():
    """The ux issue, item 10: `bench --quick` said "about 2 minutes" while the README said 84 s. Both now quote
    the measured wall times (67 s with MAVSDK installed on 2026-12-06, 60 s without; 130-155 s with the floor rows
    on 2026-12-07)."""
    help_text = " ".join(_every_help_text()["mavastsm bench"].split())
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    for figure in ("67 s", "60 s", "130-155 s"):
        assert figure in help_text and figure in readme, figure
    assert "2 minutes" not in help_text
