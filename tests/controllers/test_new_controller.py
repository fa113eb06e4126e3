"""A new controller written exactly as docs/controllers.md "Your own controller" says, flown with no other step and
no file of the package touched.

The steps, literally: a two-gain PD law in a module of the user's own (``pd_law.py``, step 1) with its preset beside
it (``pd.yaml``, step 2), flown by ``--controller pd_law:PdController`` from the folder that holds it, or by
``--controller FILE.py:PdController`` (step 3); the contract test over it (``--law``, step 4); then the same module
in an installed distribution that registers it under the entry-point group ``mavastsm.controllers`` (step 5: a
``.dist-info`` with ``entry_points.txt`` on PYTHONPATH, what ``pip install`` of such a project writes) and flown as
``--controller pd``. ``mavastsm demo`` flies it (module form, console script, working directory) and ``mavastsm
connect`` flies it against ``mavastsm sim`` (installed form); its own diagnostics land in the flight CSV. The
in-package recipe ("A law shipped with mavastsm": the same module registered in ``CONTROLLERS``) runs through the
same contract test. Bad names and a missing preset are one line and exit 2 at start-up in every command.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mavastsm.cli import main

ROOT = Path(__file__).resolve().parents[2]
MAVASTSM = str(Path(sys.executable).with_name("mavastsm"))  # the console script pip installs

LAW = '''"""A two-gain PD law written as docs/controllers.md "Your own controller" says (step 1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mavastsm.control.controller_interface import NoLimits
from mavastsm.control.sliding_surface import check_dt


@dataclass(frozen=True)
class PdGains:
    kp: tuple[float, float, float]
    kd: tuple[float, float, float]


class PdController(NoLimits):
    name = "pd"
    summary = "PD on the attitude error: u = -I0 (kp e + kd e_dot)"
    default_config = "pd.yaml"
    gains_type = PdGains

    def __init__(self, gains, model, batch_shape=()):
        self.gains = gains
        self.batch_shape = tuple(batch_shape)
        self._i0 = np.asarray(model.inertia_diag, dtype=float)
        self._kp, self._kd = np.asarray(gains.kp), np.asarray(gains.kd)
        self.reset()

    def update(self, err, dt_s):
        check_dt(dt_s)
        p = -self._i0 * self._kp * err.angle_error_rad
        d = -self._i0 * self._kd * err.euler_rate_error_rads
        u = p + d
        self._diag = {"p_term": p, "d_term": d, "u": u}
        return u

    def reset(self):
        zero = np.zeros(self.batch_shape + (3,))
        self._diag = {"p_term": zero, "d_term": zero, "u": zero}

    def diagnostics(self):
        return self._diag
'''

YAML = '''description: A two-gain PD law (docs/controllers.md, "Your own controller").
gains:
  kp:
    value: [25.0, 25.0, 25.0]
    unit: "1/s^2"
    symbol: "k_p"
    range: [0.0, 1000.0]
    doc: "Angle gain: natural frequency squared."
    source: "tests/controllers/test_new_controller.py"
  kd:
    value: [10.0, 10.0, 10.0]
    unit: "1/s"
    symbol: "k_d"
    range: [0.0, 1000.0]
    doc: "Rate gain: 2 zeta omega_n (critically damped with kp)."
    source: "tests/controllers/test_new_controller.py"
'''

ENTRY_POINTS = "[mavastsm.controllers]\npd = pd_law:PdController\n"  # step 5's table, as pip writes it

REGISTER = '''"""The in-package recipe's step 3: the law in CONTROLLERS (a pytest plugin, loaded with -p)."""
from mavastsm.control import CONTROLLERS
from pd_law import PdController

CONTROLLERS["pd"] = PdController
'''


@pytest.fixture
def law_dir(tmp_path: Path) -> Path:
    """Steps 1 and 2: the module and its preset beside it, in a folder of the user's."""
    folder = tmp_path / "my_laws"
    folder.mkdir()
    (folder / "pd_law.py").write_text(LAW, encoding="utf-8")
    (folder / "pd.yaml").write_text(YAML, encoding="utf-8")
    return folder


@pytest.fixture
def installed(tmp_path: Path) -> Path:
    """Step 5: a site folder holding the module, its preset (package data) and the distribution's metadata."""
    site = tmp_path / "site"
    (site / "pd_law-0.1.dist-info").mkdir(parents=True)
    (site / "pd_law.py").write_text(LAW, encoding="utf-8")
    (site / "pd.yaml").write_text(YAML, encoding="utf-8")
    (site / "pd_law-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: pd-law\nVersion: 0.1\n", encoding="utf-8")
    (site / "pd_law-0.1.dist-info" / "entry_points.txt").write_text(ENTRY_POINTS, encoding="utf-8")
    return site


@pytest.fixture
def clean_imports(monkeypatch):
    """In-process tests import the user's module: put sys.path and sys.modules back afterwards."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    before = set(sys.modules)
    yield
    for name in set(sys.modules) - before:
        if "pd_law" in name or "lonely_law" in name:
            del sys.modules[name]


def _env(*path: Path) -> dict:
    extra = [str(p) for p in path] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
    env = {**os.environ, "COLUMNS": "160", "PYTHONUNBUFFERED": "1"}
    env.pop("PYTHONPATH", None)
    return {**env, "PYTHONPATH": os.pathsep.join(extra)} if extra else env


@pytest.mark.parametrize("form", ["module", "file", "installed"])
def test_one_hand_computed_step(form, law_dir, installed, monkeypatch, clean_imports):
    """One step by hand. e = (0.1, -0.2, 0.05) rad, e_dot = (1, 0, -0.5) rad/s: u = -I0 (25 e + 10 e_dot)
    = -I0 * (12.5, -5, -3.75); the preset read is the one beside the module."""
    from mavastsm.control import make_controller, tracking_error
    from mavastsm.solo_model import load_solo

    folder, name = {"module": (law_dir, "pd_law:PdController"), "file": (law_dir, f"{law_dir / 'pd_law.py'}:PdController"),
                    "installed": (installed, "pd")}[form]
    if form != "file":
        monkeypatch.syspath_prepend(str(folder))
    solo = load_solo()
    ctrl = make_controller(name, solo)
    err = tracking_error([0.1, -0.2, 0.05], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    err = type(err)(err.angle_error_rad, np.array([1.0, 0.0, -0.5]), err.ref_euler_accel_radss, err.body_rates_rads, err.euler_rad)
    u = ctrl.update(err, 2.5e-3)
    np.testing.assert_allclose(u, -np.asarray(solo.inertia_diag) * np.array([12.5, -5.0, -3.75]), rtol=1e-12)
    direct = type(ctrl)(type(ctrl).gains_type(kp=(25.0, 25.0, 25.0), kd=(10.0, 10.0, 10.0)), solo)  # no YAML read
    np.testing.assert_array_equal(direct.update(err, 2.5e-3), u)
    assert ctrl.gains == direct.gains and ctrl.config_path == folder / "pd.yaml"
    assert ctrl.adaptive_gain() is None and ctrl.limit_overrides(torque_limit_nm=(1.0, 1.0, 1.0)) == {}


@pytest.mark.parametrize("form", ["installed", "module", "file", "in-package recipe"])
def test_the_contract_test_runs_over_it_and_passes(form, law_dir, installed):
    contract = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(ROOT / "tests" / "controllers" / "test_controller_contract.py")]
    argv, env = {
        "installed": (["-k", "pd"], _env(installed)),  # an installed law is in the contract test with no option
        "module": (["--law", "pd_law:PdController", "-k", "pd"], _env(law_dir)),
        "file": (["--law", f"{law_dir / 'pd_law.py'}:PdController", "-k", "pd"], _env()),
        "in-package recipe": (["-p", "register_pd", "-k", "pd"], _env(law_dir)),
    }[form]
    (law_dir / "register_pd.py").write_text(REGISTER, encoding="utf-8")
    proc = subprocess.run(contract + argv, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    m = re.search(r"(\d+) passed", proc.stdout)
    assert m and int(m.group(1)) >= 10 and "failed" not in proc.stdout and "skipped" not in proc.stdout, proc.stdout


def test_installed_laws_are_listed(installed, monkeypatch, clean_imports, capsys):
    monkeypatch.syspath_prepend(str(installed))
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["list-controllers"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.strip("│ ").startswith("pd "))
    assert "installed: pd_law:PdController" in row and str(installed / "pd.yaml") in row


def test_an_installed_name_never_replaces_a_packaged_law_and_a_broken_one_is_one_line(installed, monkeypatch, clean_imports, capsys):
    """docs: "An installed name never replaces a packaged one"; an installed law whose module fails to import is one line,
    exit 2, naming the entry point, and list-controllers still lists the others."""
    from mavastsm.control import installed_laws, law_class
    from mavastsm.control.astsm import AstsmController

    (installed / "broken_law.py").write_text("import no_such_dependency\n", encoding="utf-8")
    (installed / "pd_law-0.1.dist-info" / "entry_points.txt").write_text(
        ENTRY_POINTS + "astsm = pd_law:PdController\nbroken = broken_law:Broken\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(installed))
    assert law_class("astsm") is AstsmController and set(installed_laws()) == {"pd", "broken"}
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(["demo", "--controller", "broken", "--no-dashboard"]))
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1, err
    assert "controller 'broken': importing broken_law:Broken failed: ModuleNotFoundError" in err[0] and "no_such_dependency" in err[0]
    monkeypatch.setenv("COLUMNS", "250")
    assert main(["list-controllers"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.strip("│ ").startswith(("pd ", "broken "))]
    assert len(rows) == 2 and "installed: pd_law:PdController" in rows[0] and "no_such_dependency" in rows[1], rows


def test_simulate_flies_it_with_its_own_preset_and_another(law_dir, monkeypatch, clean_imports, capsys):
    """``simulate --controller LAW[:PRESET]``: MODULE:CLASS, then MODULE:CLASS:PRESET (a softer preset beside it)."""
    (law_dir / "pd_soft.yaml").write_text(YAML.replace("[25.0, 25.0, 25.0]", "[4.0, 4.0, 4.0]"), encoding="utf-8")
    (law_dir / "short.yaml").write_text("scenario:\n  reference: paper_steps\n  duration_s: 1.0\n", encoding="utf-8")
    monkeypatch.chdir(law_dir)
    monkeypatch.setenv("COLUMNS", "200")
    csv_path = law_dir / "run.csv"
    assert main(["simulate", "--controller", "pd_law:PdController,pd_law:PdController:pd_soft.yaml", "--scenario", "short.yaml",
                 "--dt-ms", "2", "--csv", str(csv_path)]) == 0
    assert "pd_law:PdController[pd_soft.yaml]" in capsys.readouterr().out
    with csv_path.open() as f:
        rows = list(csv.DictReader(f))
    last = {r["controller"]: (float(r["t_s"]), float(r["roll_angle_deg"])) for r in rows if float(r["t_s"]) <= 1.0}
    assert last.keys() == {"pd_law:PdController", "pd_law:PdController[pd_soft.yaml]"}
    # the -10 deg roll step at 0.5 s through e'' = -kp e - kd e' (u = -I0 (kp e + kd e_dot) on I0 phi'' = u):
    # kp 25, kd 10: critically damped, omega_n 5 rad/s: 1 - (1 + 5 t) e^(-5 t); kp 4, kd 10: poles -5 +- sqrt(21)
    p1, p2 = -5.0 + np.sqrt(21.0), -5.0 - np.sqrt(21.0)
    expected = {"pd_law:PdController": lambda t: 1.0 - (1.0 + 5.0 * t) * np.exp(-5.0 * t),
                "pd_law:PdController[pd_soft.yaml]": lambda t: 1.0 - (p2 * np.exp(p1 * t) - p1 * np.exp(p2 * t)) / (p2 - p1)}
    for label, (t_s, roll_deg) in last.items():
        assert roll_deg == pytest.approx(-10.0 * expected[label](t_s - 0.5), abs=0.05), (label, t_s, roll_deg)


def test_a_sweep_flies_it_in_its_spawned_worker(law_dir, monkeypatch, clean_imports):
    """A sweep file lists MODULE:CLASS like a key; the local worker (a spawned process) imports it too."""
    (law_dir / "sweep.yaml").write_text("sweep:\n  controllers: ['pd_law:PdController']\n  duration_s: 5.0\n"
                                        "  variables:\n    disturbance_roll_nm: {grid: [0.0]}\n", encoding="utf-8")
    monkeypatch.chdir(law_dir)
    assert main(["sweep", "sweep.yaml", "--workers", "1", "--no-progress", "--out-dir", str(law_dir / "out")]) == 0
    with (law_dir / "out" / "table.csv").open() as f:
        (row,) = list(csv.DictReader(f))
    assert row["controller"] == "pd_law:PdController" and row["step_deg_roll"] == "-10.0", row
    assert 0.5 < float(row["settling_5pct_s_roll"]) < 5.0 and row["nonfinite_outputs"] == "0", row


def _command(kind: str, law: str, folder: Path) -> list[str]:
    if kind == "demo":
        return ["demo", "--controller", law, "--no-dashboard"]
    if kind == "connect":
        return ["connect", "udpout:127.0.0.1:9", "--controller", law, "--no-dashboard"]
    if kind == "simulate":
        return ["simulate", "--controller", law]
    if kind == "sweep":
        spec = folder / "sweep.yaml"
        spec.write_text(f"sweep:\n  controllers: ['{law}']\n  variables:\n    disturbance_roll_nm: {{grid: [0.0]}}\n", encoding="utf-8")
        return ["sweep", str(spec)]
    (folder / "pd.yaml").write_text(YAML, encoding="utf-8")
    return ["check-config", str(folder / "pd.yaml"), "--controller", law]


BAD_LAWS = [
    ("no_such_law:PdController", "no module named 'no_such_law'"),
    ("lonely_law:NoSuchClass", "has no 'NoSuchClass'; its laws: LonelyController"),
    ("{folder}/missing.py:PdController", "missing.py: no such file"),
    ("lonely_law:PdGains", "PdGains lacks gains_type, default_config, name, update"),
]
NO_PRESET = ("lonely_law:LonelyController", "lonely.yaml (default_config) not found")  # check-config is given a preset


@pytest.mark.parametrize("kind, law, needle", [(k, *bad) for k in ("demo", "connect", "simulate", "sweep", "check-config") for bad in BAD_LAWS]
                         + [(k, *NO_PRESET) for k in ("demo", "connect", "simulate", "sweep")])
def test_a_bad_law_is_one_line_and_exit_2_at_start_up(kind, law, needle, tmp_path, monkeypatch, clean_imports, capsys):
    """Unknown module, unknown class, no such file, a class that is not a law, no preset beside the module."""
    (tmp_path / "lonely_law.py").write_text(LAW.replace("PdController", "LonelyController").replace('"pd.yaml"', '"lonely.yaml"'), encoding="utf-8")
    monkeypatch.chdir(tmp_path)  # MODULE:CLASS falls back to the working directory
    law = law.format(folder=tmp_path)
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(_command(kind, law, tmp_path)))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and f"mavastsm {kind}" in err[0], err


def _flight_csv_checks(log: Path) -> None:
    """The law's own diagnostics reach the flight CSV, and u = p_term + d_term as the law wrote them."""
    from mavastsm.bridge.record.flight_log import read_flight_rows

    header = log.read_text().splitlines()[0].split(",")
    assert [c for c in header if c.startswith("diag_")] == [f"diag_{k}_{a}" for k in ("p_term", "d_term") for a in ("roll", "pitch", "yaw")]
    engaged = [r.sample for r in read_flight_rows(log) if r.phase == "engaged" and np.isfinite(r.sample.u_nm[0])]
    assert len(engaged) > 1000
    for s in engaged[-50:]:
        extra = dict(s.extra)
        np.testing.assert_allclose(np.add(extra["p_term"], extra["d_term"]), s.u_nm, rtol=1e-5, atol=1e-9)


@pytest.mark.sitl
@pytest.mark.slow
def test_mavastsm_demo_flies_it_from_the_folder_that_holds_it(law_dir, tmp_path):
    proc = subprocess.run([MAVASTSM, "demo", "--speedup", "10", "--no-dashboard", "--controller", "pd_law:PdController",
                           "--log", str(tmp_path / "logs")], capture_output=True, text=True, env=_env(), cwd=law_dir, timeout=180)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "mavastsm demo: pd_law:PdController on scenario" in out
    assert "end: duration complete; failsafe: none" in out and "landed: yes; disarmed: yes" in out
    _flight_csv_checks(next((tmp_path / "logs").glob("*.csv")))


@pytest.mark.sitl
@pytest.mark.slow
def test_mavastsm_connect_flies_the_installed_law_against_mavastsm_sim(installed, tmp_path):
    env = _env(installed)
    procs = []
    try:
        sim = subprocess.Popen([MAVASTSM, "sim", "--listen", "127.0.0.1:0", "--lockstep", "--scenario", "nominal"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
        procs.append(sim)
        first = sim.stdout.readline()
        port = re.search(r"udp 127\.0\.0\.1:(\d+)", first)
        assert port, f"sim did not print its port: {first!r}"
        bridge = subprocess.Popen([MAVASTSM, "connect", f"udpout:127.0.0.1:{port.group(1)}", "--controller", "pd", "--mode", "GUIDED",
                                   "--arm", "--takeoff", "0.5", "--on-exit", "LAND", "--no-dashboard", "--log", str(tmp_path),
                                   "--set", "timing.stale_timeout_s=0.5", "--set", "timing.overrun_cycles=100000"],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
        procs.append(bridge)
        out, err = bridge.communicate(timeout=150)
        assert bridge.returncode == 0, f"connect exited {bridge.returncode}: {out[-1500:]} {err[-1500:]}"
        assert "end: duration complete" in out and "hand-back: LAND accepted" in out, out[-2000:]
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
            p.communicate(timeout=20)
    _flight_csv_checks(next(tmp_path.glob("*.csv")))
    sidecar = json.loads(next(tmp_path.glob("*.json")).read_text())
    assert sidecar["controller"] == "pd" and sidecar["controller_config"] == str(installed / "pd.yaml"), sidecar
