"""A new controller added exactly as docs/controllers.md "Adding a controller" says, flown with no other step.

The three steps, literally: the law module (step 1), its YAML (step 2), the CONTROLLERS entry (step 3). The only
difference from a real addition is where the files live: a temporary directory on PYTHONPATH (with absolute
imports and ``default_config`` the YAML's path), so the test leaves the package untouched. Then the contract test
runs over it, ``mavastsm demo`` (lockstep) flies the paper's steps with it end to end, and its own diagnostics
land in the flight CSV. Before the safe-simple issue this failed at start-up (the bridge added
``torque_limit_enabled`` overrides to any law) and the equivalence test needed a private ``_single``. The law is
built from a gains object and a model (no YAML in its constructor); ``make_controller`` reads its preset.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]

LAW = '"""A two-gain PD law written as docs/controllers.md "Adding a controller" says (step 1)."""\n\nfrom __future__ import annotations\n\nfrom dataclasses import dataclass\nfrom pathlib import Path\n\nimport numpy as np\n\nfrom mavastsm.control.controller_interface import NoLimits\nfrom mavastsm.control.sliding_surface import check_dt\n\n\n@dataclass(frozen=True)\nclass PdGains:\n    kp: tuple[float, float, float]\n    kd: tuple[float, float, float]\n\n\nclass PdController(NoLimits):\n    name = "pd"\n    summary = "PD on the attitude error: u = -I0 (kp e + kd e_dot)"\n    default_config = str(Path(__file__).with_name("pd.yaml"))\n    gains_type = PdGains\n\n    def __init__(self, gains, model, batch_shape=()):\n        self.gains = gains\n        self.batch_shape = tuple(batch_shape)\n        self._i0 = np.asarray(model.inertia_diag, dtype=float)\n        self._kp, self._kd = np.asarray(self.gains.kp), np.asarray(self.gains.kd)\n        self.reset()\n\n    def update(self, err, dt_s):\n        check_dt(dt_s)\n        p = -self._i0 * self._kp * err.angle_error_rad\n        d = -self._i0 * self._kd * err.euler_rate_error_rads\n        u = p + d\n        self._diag = {"p_term": p, "d_term": d, "u": u}\n        return u\n\n    def reset(self):\n        zero = np.zeros(self.batch_shape + (3,))\n        self._diag = {"p_term": zero, "d_term": zero, "u": zero}\n\n    def diagnostics(self):\n        return self._diag\n'

YAML = 'description: A two-gain PD law (docs/controllers.md, "Adding a controller").\ngains:\n  kp:\n    value: [25.0, 25.0, 25.0]\n    unit: "1/s^2"\n    symbol: "k_p"\n    range: [0.0, 1000.0]\n    doc: "Angle gain: natural frequency squared."\n    source: "tests/controllers/test_new_controller.py"\n  kd:\n    value: [10.0, 10.0, 10.0]\n    unit: "1/s"\n    symbol: "k_d"\n    range: [0.0, 1000.0]\n    doc: "Rate gain: 2 zeta omega_n (critically damped with kp)."\n    source: "tests/controllers/test_new_controller.py"\n'

REGISTER = '"""Step 3: register the law in CONTROLLERS (also a pytest plugin, loaded with -p, so the contract test sees it)."""\nfrom mavastsm.control import CONTROLLERS\nfrom pd_law import PdController\n\nCONTROLLERS["pd"] = PdController\n'


@pytest.fixture
def law_dir(tmp_path: Path) -> Path:
    (tmp_path / "pd_law.py").write_text(LAW, encoding="utf-8")
    (tmp_path / "pd.yaml").write_text(YAML, encoding="utf-8")
    (tmp_path / "register_pd.py").write_text(REGISTER, encoding="utf-8")
    return tmp_path


def _env(law_dir: Path) -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(law_dir), os.environ.get("PYTHONPATH", "")]),
            "COLUMNS": "160", "PYTHONUNBUFFERED": "1"}


def test_one_hand_computed_step(law_dir, monkeypatch):
    """Step 3's last line: one step by hand. e = (0.1, -0.2, 0.05) rad, e_dot = (1, 0, -0.5) rad/s:
    u = -I0 (25 e + 10 e_dot) = -I0 * (12.5, -5, -3.75)."""
    monkeypatch.syspath_prepend(str(law_dir))
    import register_pd  # noqa: F401
    from mavastsm.control import CONTROLLERS, make_controller, tracking_error
    from mavastsm.solo_model import load_solo

    try:
        solo = load_solo()
        ctrl = make_controller("pd", solo)
        err = tracking_error([0.1, -0.2, 0.05], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        err = type(err)(err.angle_error_rad, np.array([1.0, 0.0, -0.5]), err.ref_euler_accel_radss, err.body_rates_rads, err.euler_rad)
        u = ctrl.update(err, 2.5e-3)
        np.testing.assert_allclose(u, -np.asarray(solo.inertia_diag) * np.array([12.5, -5.0, -3.75]), rtol=1e-12)
        from pd_law import PdController, PdGains  # the same law built from a gains object, no YAML read

        direct = PdController(PdGains(kp=(25.0, 25.0, 25.0), kd=(10.0, 10.0, 10.0)), solo)
        np.testing.assert_array_equal(direct.update(err, 2.5e-3), u)
        assert ctrl.gains == direct.gains and ctrl.config_path.name == "pd.yaml"
        assert ctrl.adaptive_gain() is None and ctrl.limit_overrides(torque_limit_nm=(1.0, 1.0, 1.0)) == {}
    finally:
        CONTROLLERS.pop("pd", None)
        for m in ("register_pd", "pd_law"):
            sys.modules.pop(m, None)


def test_the_contract_test_runs_over_it_and_passes(law_dir):
    proc = subprocess.run([sys.executable, "-m", "pytest", "-p", "register_pd", "-q", "-p", "no:cacheprovider",
                           str(ROOT / "tests" / "controllers" / "test_controller_contract.py"), "-k", "pd"],
                          capture_output=True, text=True, env=_env(law_dir), cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    m = re.search(r"(\d+) passed", proc.stdout)
    assert m and int(m.group(1)) >= 8 and "failed" not in proc.stdout, proc.stdout


@pytest.mark.sitl
@pytest.mark.slow
def test_mavastsm_demo_flies_it(law_dir, tmp_path):
    code = ("import register_pd\nfrom mavastsm.cli import main\n"
            f"raise SystemExit(main(['demo', '--speedup', '10', '--no-dashboard', '--controller', 'pd', '--log', {str(tmp_path / 'logs')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_env(law_dir), timeout=180)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "mavastsm demo: pd on scenario" in out
    assert "end: duration complete; failsafe: none" in out and "landed: yes; disarmed: yes" in out
    log = next((tmp_path / "logs").glob("*.csv"))
    header = log.read_text().splitlines()[0].split(",")
    assert [c for c in header if c.startswith("diag_")] == [f"diag_{k}_{a}" for k in ("p_term", "d_term") for a in ("roll", "pitch", "yaw")]
    from mavastsm.bridge.flight_log import read_flight_rows

    engaged = [r.sample for r in read_flight_rows(log) if r.phase == "engaged" and np.isfinite(r.sample.u_nm[0])]
    assert len(engaged) > 1000
    for s in engaged[-50:]:  # u = p_term + d_term, as the law wrote them
        extra = dict(s.extra)
        np.testing.assert_allclose(np.add(extra["p_term"], extra["d_term"]), s.u_nm, rtol=1e-5, atol=1e-9)
