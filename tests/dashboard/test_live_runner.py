"""DashboardRunner: plain vs Live selection, keys, pause, error containment, clean shutdown.

Waits are on conditions (frame/tick counters) with timeouts, never on fixed sleeps.
"""

from __future__ import annotations

import sys
import threading
import time

import pytest

from mavastsm.dashboard.live_view import DashboardRunner
from mavastsm.telemetry import TelemetryBuffer


def wait_until(predicate, timeout_s: float = 10.0) -> bool:
    done = threading.Event()
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        done.wait(0.005)
    return True


@pytest.fixture
def runners():
    started: list[DashboardRunner] = []
    yield started
    for runner in started:
        runner.stop()


def test_not_a_terminal_selects_plain_status_lines(buffer_maker, console_maker, runners):
    console = console_maker(200, 24, terminal=False)
    runner = DashboardRunner(buffer_maker(n=100), console=console, keys=False, status_period_s=0.02)
    assert runner.plain
    runners.append(runner.start())
    assert wait_until(lambda: runner.frames_rendered >= 3)
    runner.stop()
    lines = console.export_text().splitlines()
    assert len(lines) >= 3
    assert all(line.startswith("t=") and "failsafe none" in line for line in lines)
    assert "\x1b" not in console.file.getvalue()  # no cursor control codes in plain mode


def test_live_view_draws_frames_on_a_terminal(buffer_maker, console_maker, runners):
    console = console_maker(100, 40, terminal=True)
    runner = DashboardRunner(buffer_maker(n=100), refresh_hz=50.0, console=console, keys=False)
    assert not runner.plain
    runners.append(runner.start())
    assert wait_until(lambda: runner.frames_rendered >= 3)
    runner.stop()
    out = console.file.getvalue()
    assert "σ [rad/s]" in out and "link / vehicle" in out and runner.render_errors == 0


def test_plain_false_forces_live_and_plain_true_forces_lines(buffer_maker, console_maker):
    assert not DashboardRunner(TelemetryBuffer(), plain=False, console=console_maker(80, 24)).plain
    assert DashboardRunner(TelemetryBuffer(), plain=True, console=console_maker(80, 24, terminal=True)).plain


def test_q_calls_on_quit_and_p_pauses_rendering(buffer_maker, console_maker, runners):
    quits = []
    console = console_maker(100, 40, terminal=True)
    runner = DashboardRunner(buffer_maker(n=100), refresh_hz=100.0, on_quit=lambda: quits.append(1),
                             console=console, keys=False)
    runners.append(runner.start())
    assert wait_until(lambda: runner.frames_rendered >= 2)
    runner.handle_key("q")
    assert quits == [1]
    runner.handle_key("p")
    assert runner.paused
    assert wait_until(lambda: "PAUSED" in console.file.getvalue())  # one frame shows the pause
    frames, ticks = runner.frames_rendered, runner.ticks
    assert wait_until(lambda: runner.ticks >= ticks + 5)
    assert runner.frames_rendered == frames  # loop keeps ticking, nothing drawn
    runner.handle_key("p")
    assert wait_until(lambda: runner.frames_rendered > frames)


def test_render_errors_are_counted_not_raised(console_maker, runners):
    class BrokenBuffer(TelemetryBuffer):
        def snapshot(self, max_samples=None):
            raise RuntimeError("boom")

    runner = DashboardRunner(BrokenBuffer(), refresh_hz=100.0, console=console_maker(80, 24, terminal=True),
                             keys=False)
    runners.append(runner.start())
    assert wait_until(lambda: runner.render_errors >= 3)
    assert runner.running and runner.last_render_error == "RuntimeError: boom"


def test_context_manager_stops_thread_and_leaves_the_switch_interval_alone(buffer_maker, console_maker):
    """Process-wide tuning is the command line's (mavastsm.runtime_tuning), not the dashboard's (issue 19): drawn in a
    thread here, the runner says so (draws_in_this_process) and leaves the interpreter's switch interval as it is."""
    before = sys.getswitchinterval()
    with DashboardRunner(buffer_maker(n=10), console=console_maker(80, 24, terminal=True), keys=False) as runner:
        assert runner.draws_in_this_process
        assert sys.getswitchinterval() == before
        assert wait_until(lambda: runner.frames_rendered >= 1)
    assert not runner.running
    assert sys.getswitchinterval() == before
    assert not any(t.name.startswith("mavastsm-dashboard") for t in threading.enumerate())


def test_the_process_tuning_sets_the_switch_interval_for_a_dashboard_drawn_here(buffer_maker, console_maker):
    """What the dashboard did for itself in thread mode (interval at most 0.5 ms while it draws), the command line's
    ProcessTuning does for the process: bridge.yaml's timing.gil_switch_interval_s, restored at the end."""
    from mavastsm.bridge.bridge_config import load_bridge_config
    from mavastsm.runtime_tuning import ProcessTuning

    timing = load_bridge_config().timing
    assert timing.gil_switch_interval_s == pytest.approx(0.0005)
    before = sys.getswitchinterval()
    with ProcessTuning(timing), DashboardRunner(buffer_maker(n=10), console=console_maker(80, 24, terminal=True), keys=False) as runner:
        assert runner.draws_in_this_process
        assert sys.getswitchinterval() == pytest.approx(timing.gil_switch_interval_s)
        assert wait_until(lambda: runner.frames_rendered >= 1)
    assert sys.getswitchinterval() == before


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf")])
def test_bad_refresh_rate_is_rejected_with_a_clear_message(bad):
    with pytest.raises(ValueError, match="refresh_hz"):
        DashboardRunner(TelemetryBuffer(), refresh_hz=bad)


def test_process_isolation_draws_in_a_child_and_reaps_it(buffer_maker, tmp_path, runners):
    out_path = tmp_path / "frames.txt"
    buf = buffer_maker(n=100)
    with open(out_path, "wb") as out:
        runner = DashboardRunner(buf, refresh_hz=50.0, plain=False, keys=False, isolation="process",
                                 process_output=out, process_size=(120, 40))
        assert runner.isolation == "process"
        runners.append(runner.start())
        child = runner._process
        assert wait_until(lambda: runner.frames_rendered >= 3)
        buf.publish(buf.snapshot().history[-1])  # new samples keep flowing while drawing
        runner.stop()
    assert child.returncode == 0  # exited on the stop message, not killed
    text = out_path.read_text(encoding="utf-8")
    assert "σ [rad/s]" in text and "4936 cycles, 0 missed" in text and runner.render_errors == 0


def test_auto_isolation_draws_in_thread_with_an_injected_console(console_maker):
    runner = DashboardRunner(TelemetryBuffer(), plain=False, console=console_maker(80, 24, terminal=True))
    assert runner.isolation == "thread"


@pytest.mark.parametrize("mode", ["plain", "thread", "process"])
def test_print_line_shows_messages_in_every_mode(buffer_maker, console_maker, tmp_path, runners, mode):
    out_path = tmp_path / "frames.txt"
    with open(out_path, "wb") as out:
        if mode == "process":
            runner = DashboardRunner(buffer_maker(n=10), refresh_hz=50.0, plain=False, keys=False,
                                     isolation="process", process_output=out, process_size=(100, 40))
        else:
            console = console_maker(100, 40, terminal=mode == "thread")
            runner = DashboardRunner(buffer_maker(n=10), refresh_hz=50.0, plain=mode == "plain", console=console,
                                     keys=False, status_period_s=0.02)
        runners.append(runner.start())
        assert wait_until(lambda: runner.frames_rendered >= 1)
        runner.print_line("hand-back: LOITER [accepted]")
        assert wait_until(lambda: runner.frames_rendered >= 4)
        runner.stop()
    text = out_path.read_text(encoding="utf-8") if mode == "process" else runner.console.file.getvalue()
    assert text.count("hand-back: LOITER [accepted]") == 1


def test_renderer_protocol_replays_chunks_and_draws_only_when_asked(buffer_maker, console_maker):
    import io
    import pickle

    from mavastsm.dashboard.render_process import FrameUpdate, run_renderer

    src = buffer_maker(n=120).snapshot()
    stream = io.BytesIO()
    chunks = [src.history[:50], src.history[50:100], src.history[100:]]
    for i, chunk in enumerate(chunks):
        last = i == len(chunks) - 1
        update = FrameUpdate(chunk, src.link if last else None, src.session if last else None, None, False,
                             draw=last, messages=("link re-asserted",) if last else ())
        pickle.dump(("frame", update), stream)
    pickle.dump(("stop", None), stream)
    stream.seek(0)
    console = console_maker(120, 40, terminal=True)
    assert run_renderer(stream, console, capacity=4000, window_s=5.0) == 0
    out = console.file.getvalue()
    assert out.count("TV(u)") == 2  # one frame for the three chunks, plus Live's redraw on stop
    assert "link re-asserted" in out and "4936 cycles, 0 missed" in out and "paper-steps t=0.3/12.0 s" in out


def test_child_death_is_counted_and_stop_still_returns(buffer_maker, tmp_path, runners):
    with open(tmp_path / "frames.txt", "wb") as out:
        runner = DashboardRunner(buffer_maker(n=10), refresh_hz=50.0, plain=False, keys=False, isolation="process",
                                 process_output=out, process_size=(100, 40))
        runners.append(runner.start())
        assert wait_until(lambda: runner.frames_rendered >= 1)
        runner._process.kill()
        assert wait_until(lambda: runner.render_errors >= 1)
        assert "BrokenPipeError" in runner.last_render_error or "OSError" in runner.last_render_error
        runner.stop()
    assert not runner.running


def test_prints_in_the_bridge_process_appear_above_the_child_view(buffer_maker, capfd, runners):
    original = sys.stdout
    runner = DashboardRunner(buffer_maker(n=10), refresh_hz=50.0, plain=False, keys=False, isolation="process",
                             process_size=(100, 40))  # draws on the inherited fd 1 (captured by capfd)
    runners.append(runner.start())
    assert sys.stdout is not original  # forwarded while the child owns the terminal
    assert wait_until(lambda: runner.frames_rendered >= 1)
    print("ATTITUDE at 183 Hz < half of 400 Hz: SET_MESSAGE_INTERVAL re-sent")
    print("partial line without newline", end="")
    assert wait_until(lambda: runner.frames_rendered >= 4)
    runner.stop()
    assert sys.stdout is original
    out = capfd.readouterr().out
    assert out.count("SET_MESSAGE_INTERVAL re-sent") == 1 and out.count("partial line without newline") == 1
    assert "σ [rad/s]" in out
