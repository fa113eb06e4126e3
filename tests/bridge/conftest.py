"""The bridges these tests run in-process run in the interpreter as ``mavastsm connect`` sets it up
(mavastsm.runtime_tuning: bridge.yaml's switch interval), which the Bridge class itself no longer does (issue 19)."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def process_as_connect_sets_it_up():
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.runtime_tuning import ProcessTuning

    with ProcessTuning(load_bridge_config().timing):
        yield
