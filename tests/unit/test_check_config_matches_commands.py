"""The ux issue, item 2: `check-config` said "valid" (exit 0) for files `connect` and `simulate` reject (exit 2). Now
it runs the loaders the commands run: the same bad file gives the same one-line error and exit 2 from both."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavastsm.cli import main

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _bad(tmp_path: Path, source: str, old: str, new: str) -> Path:
    text = (CONFIGS / source).read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / Path(source).name
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


CASES = [
    # (file, edit, the rule named, the command that consumes such a file)
    ("controllers/astsm.yaml", "  surface_slope:", "  surfce_slope:", "gains.surfce_slope",
     lambda p: ["simulate", "--controller", f"astsm:{p}", "--scenario", "nominal"]),
    ("controllers/astsm.yaml", "    value: 6.60", "    value: six", "gains.gamma1",
     lambda p: ["connect", "udpout:127.0.0.1:9", "--controller-config", str(p)]),
    ("controllers/astsm.yaml", "gains:", "gainz:", "gain",
     lambda p: ["connect", "udpout:127.0.0.1:9", "--controller-config", str(p)]),
    ("bridge.yaml", "\nlimits:", "\nlimitz:", "limit",
     lambda p: ["connect", "udpout:127.0.0.1:9", "--config", str(p)]),
    ("vehicle/solo.yaml", "rigid_body:", "rigid_bodi:", "rigid_bod",
     lambda p: ["connect", "udpout:127.0.0.1:9", "--vehicle", str(p)]),
    ("sim_profiles/arducopter-4.5-quick.yaml", "  prearm_delay_s:", "  prearm_delai_s:", "habits.prearm_delai_s",
     lambda p: ["sim", "--listen", "127.0.0.1:0", "--profile", str(p)]),
]


@pytest.mark.parametrize("source,old,new,rule,command", CASES, ids=[c[3] for c in CASES])
def test_check_config_rejects_what_the_commands_reject(tmp_path, capsys, source, old, new, rule, command):
    path = _bad(tmp_path, source, old, new)
    assert main(["check-config", str(path)]) == 2
    check_err = capsys.readouterr().err.strip().splitlines()
    assert main(command(path)) == 2
    cmd_err = capsys.readouterr().err.strip().splitlines()
    for err in (check_err, cmd_err):
        assert len(err) == 1 and str(path) in err[0] and rule in err[0], err


@pytest.mark.parametrize("name", sorted(str(p.relative_to(CONFIGS)) for p in CONFIGS.rglob("*.yaml")))
def test_every_packaged_config_is_valid(capsys, name):
    assert main(["check-config", str(CONFIGS / name)]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("valid ")
