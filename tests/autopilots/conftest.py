"""Fixtures for the tests against genuine autopilots (``pytest -m ardupilot``, ``pytest -m px4``).

Configuration: ``MAVASTSM_ARDUCOPTER`` (the SITL binary or its folder) and ``MAVASTSM_PX4`` (PX4's build
folder). Without it these tests skip with a one-line reason; under CI (``CI`` set, as ``.ci/run`` runs)
a missing or broken autopilot is a failure, never a skip. Every instance runs in a private network
namespace (sim/genuine_sitl.py) and is killed by PID when the test ends, pass or fail.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from mavastsm_sim.genuine_observer import boot_arducopter, boot_px4, boot_px4_solo_physics  # noqa: E402

from mavastsm_sim.genuine_sitl import SitlUnavailable, arducopter_paths, px4_paths  # noqa: E402


def _configured(paths_fn):
    try:
        return paths_fn()
    except SitlUnavailable as exc:
        if os.environ.get("CI"):
            pytest.fail(f"CI: {exc}", pytrace=False)
        pytest.skip(str(exc))


def _namespaces_or_fail() -> None:
    if os.geteuid() != 0 and not os.environ.get("CI"):
        pytest.skip("genuine SITL tests run each autopilot in a private network namespace, which needs root")


@pytest.fixture(scope="session")
def arducopter_build():
    _namespaces_or_fail()
    return _configured(arducopter_paths)


@pytest.fixture(scope="session")
def px4_build():
    _namespaces_or_fail()
    return _configured(px4_paths)


RESULTS_PATH = Path(os.environ.get("MAVASTSM_GENUINE_RESULTS", HERE.parents[1] / "out" / "autopilots" / "results.json"))


@pytest.fixture
def record(request):
    """record(label, **values): what a genuine-SITL test measured, appended to out/autopilots/results.json
    (MAVASTSM_GENUINE_RESULTS overrides) and printed, for docs and the closing notes."""
    import json

    def _record(label: str, **values) -> None:
        RESULTS_PATH.parent.mkdir(parents=True, exist_ok=True)
        rows = json.loads(RESULTS_PATH.read_text()) if RESULTS_PATH.exists() else []
        rows.append({"test": request.node.nodeid, "label": label, **values})
        RESULTS_PATH.write_text(json.dumps(rows, indent=1))
        print(f"{label}: {values}")

    return _record


@pytest.fixture
def cold_arducopter(arducopter_build):
    with boot_arducopter(arducopter_build, fast_prearm=False) as v:
        yield v


@pytest.fixture(scope="module")
def arducopter(arducopter_build):
    """One ArduCopter per test module, ready to arm; each test leaves it landed and disarmed."""
    with boot_arducopter(arducopter_build, fast_prearm=True) as v:
        yield v


@pytest.fixture
def arducopter_vehicle(arducopter):
    yield arducopter
    arducopter.after_test()


@pytest.fixture
def cold_px4(px4_build):
    """PX4 with SIH just started: the test starts the bridge within seconds, as a newcomer does."""
    with boot_px4(px4_build, ready=False) as v:
        yield v


@pytest.fixture
def cold_px4_solo(px4_build):
    """PX4 tuned as a Solo flying our Solo physics (sim/px4_hil.py), just started, keeping 120 s of true attitude."""
    with boot_px4_solo_physics(px4_build, attitude_history_s=120.0) as v:
        yield v


@pytest.fixture(scope="module", params=["sih", "solo_physics"])
def px4(request, px4_build):
    """One PX4 per test module and vehicle, ready to arm: SIH's stock quad, and PX4 tuned as a Solo flying our Solo
    physics over its simulator interface (sim/px4_hil.py); each test leaves it landed and disarmed."""
    boot = boot_px4 if request.param == "sih" else boot_px4_solo_physics
    with boot(px4_build, ready=True) as v:
        yield v


@pytest.fixture
def px4_vehicle(px4):
    yield px4
    px4.after_test()
