"""Entry points: ``mavastsm sim`` as a real process (talks MAVLink, stops cleanly on SIGTERM with exit 0),
``python -m sim`` from the source checkout, one-line errors with exit status 2 for bad options."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from mavlink_peer_tools import Gcs

REPO = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "mavastsm.cli", "sim"]


def test_sim_process_talks_mavlink_and_stops_cleanly_on_sigterm(tmp_path):
    proc = subprocess.Popen(CLI + ["--listen", "127.0.0.1:0", "--lockstep"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, cwd=tmp_path)
    gcs = None
    try:
        banner = proc.stdout.readline()
        match = re.search(r"udp 127\.0\.0\.1:(\d+)", banner)
        assert match, banner
        gcs = Gcs(int(match.group(1)))
        hb = gcs.hello(timeout_s=10.0)
        assert (hb.get_srcSystem(), hb.type, hb.autopilot) == (1, 2, 3)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10.0)
        assert proc.returncode == 0, err
        assert "stopped at t=" in out
        # benchmarks/bridge_realtime.py reads the sim's late-ATTITUDE count from this line
        assert re.search(r"\d+ ATTITUDE sent > 1 ms late, \d+ re-bases", out), out
    finally:
        if gcs is not None:
            gcs.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5.0)


def test_python_dash_m_sim_from_source_checkout_documents_options_with_units():
    out = subprocess.run([sys.executable, "-m", "sim", "--help"], cwd=REPO, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    for option in ("--out", "--listen", "--speedup", "--lockstep", "--scenario", "--seed", "--physics-rate-hz",
                   "--profile", "--set", "--signing-key", "--verbose", "--duration-s"):
        assert option in out.stdout
    assert "[Hz]" in out.stdout and "[s]" in out.stdout and "[ms]" in out.stdout


def test_bad_options_give_one_line_error_and_exit_2(tmp_path, capsys):
    from mavastsm.cli import main

    cases = [["--speedup", "0"], ["--listen", "nohostport"], ["--signing-key", str(tmp_path / "missing.key")],
             ["--physics-rate-hz", "nan"], ["--scenario", "no_such_scenario"], ["--home", "91,0,0"]]
    for extra in cases:
        argv = ["sim"] + (["--listen", "127.0.0.1:0"] if extra[0] != "--listen" else []) + extra
        try:
            status = main(argv)
        except SystemExit as exc:  # argparse rejects the value itself
            status = exc.code
        err = capsys.readouterr().err
        assert status == 2, (extra, err)
        error_lines = [line for line in err.splitlines() if "error" in line]
        assert len(error_lines) == 1, (extra, err)
