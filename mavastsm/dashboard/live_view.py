"""The dashboard runner: a background thread that reads ``TelemetryBuffer`` snapshots at a fixed
rate and shows them, as a rich ``Live`` view or as plain status lines once per second.

The control loop never waits on the terminal: the only shared step is ``TelemetryBuffer.snapshot``
(a deque copy under a short lock). The refresh rate is independent of the control rate. Rendering
errors are counted and shown, never raised into the caller.

Isolation: building and drawing a frame with rich is many control periods of pure Python. Done in the
bridge's process, that time holds the interpreter lock and a 400 Hz control thread waiting for it
shows it in its latency tail. So by default (``isolation="auto"`` with the real terminal) the Live
view is drawn by a child process (``render_process``); this process only forwards the new samples
(``TelemetryBuffer.samples_since`` + pickle, a small fraction of a frame's cost). With an injected ``console``
(tests, screenshots) or ``isolation="thread"`` it draws in a thread here (``draws_in_this_process``); the
interpreter switch interval that shortens the control thread's lock waits is then the process's business, set by
the command line (``mavastsm.runtime_tuning``), never by this class.
``tests/dashboard/test_dashboard_loop_impact.py`` measures the effect on a real bridge.

Usage::

    with DashboardRunner(buffer, on_quit=bridge.request_stop):
        bridge.run()
"""

from __future__ import annotations

import collections
import io
import math
import os
import pickle
import select
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Callable

from rich.console import Console
from rich.live import Live

from ..telemetry import TelemetryBuffer
from .panels import build_view
from .render_process import FrameUpdate
from .status_lines import format_status_line

PLAIN_PERIOD_S = 1.0
MAX_SAMPLES_PER_UPDATE = 1000  # newest samples forwarded after a pause or at start-up
PICKLE_CHUNK_SAMPLES = 50  # samples pickled per call, well under a control period: the control thread can take the lock in between
RENDER_NICENESS = 19  # fallback where SCHED_IDLE is unavailable
ISOLATIONS = ("auto", "process", "thread")


class _LineForwarder(io.TextIOBase):
    """Stands in for ``sys.stdout``/``sys.stderr`` while the drawing process owns the terminal:
    complete lines written by anyone in this process go to ``DashboardRunner.print_line`` (and so
    appear above the view instead of being overwritten by it)."""

    def __init__(self, sink: Callable[[str], None], original) -> None:
        super().__init__()
        self._sink = sink
        self.original = original
        self._partial = ""
        self._lock = threading.Lock()

    def write(self, text: str) -> int:
        with self._lock:
            self._partial += text
            *lines, self._partial = self._partial.split("\n")
        for line in lines:
            self._sink(line)
        return len(text)

    def flush_partial(self) -> None:
        with self._lock:
            rest, self._partial = self._partial, ""
        if rest:
            self._sink(rest)

    def flush(self) -> None:
        pass

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return self.original.isatty()

    def fileno(self) -> int:
        return self.original.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self.original, "encoding", "utf-8")


def read_keys(stop: threading.Event, on_key: Callable[[str], None]) -> None:
    """Hand each key typed on the terminal to ``on_key`` (cbreak mode, restored after) until ``stop`` is set; a
    stdin that is no terminal or breaks ends it quietly (a broken stdin must not take the dashboard down)."""
    import termios
    import tty

    try:
        fd = sys.stdin.fileno()
        saved = termios.tcgetattr(fd)
    except (OSError, ValueError, termios.error):
        return
    try:
        tty.setcbreak(fd)
        while not stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.1)
            if ready:
                data = os.read(fd, 32)
                if not data:
                    return
                for ch in data.decode(errors="ignore"):
                    on_key(ch)
    except Exception:  # noqa: BLE001
        return
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


class DashboardRunner:
    """Show the telemetry of a running bridge until stopped.

    Parameters
    ----------
    telemetry : the buffer the control loop publishes into (read-only here)
    refresh_hz : [Hz] Live view refresh rate (default 10); plain lines are always once per second
    on_quit : called (from the key-reader thread) when the operator presses ``q``; the bridge treats
        it like Ctrl-C: level hold, hand back, exit. Must be thread-safe and return quickly.
    plain : True for plain status lines, False for the Live view, None to choose plain when the
        console is not a terminal (pipes, CI, systemd)
    console : rich Console to draw on (default: stdout); tests pass a recording console
    window_s : [s] history window of the sparklines and the chattering figure
    keys : read keys from stdin (cbreak mode, restored on stop); None = only when stdin is a TTY
    status_period_s : [s] period of the plain status lines (1 s; tests shorten it)
    isolation : where the Live view is drawn: "process" (child process, keeps rendering off the
        bridge's interpreter lock), "thread" (here), or "auto" = process unless a console is given
    process_output : where the child process draws (default: inherit stdout); with
        ``process_size`` (width, height) fixed, for tests
    redirect_output : while the child process draws on this terminal, route this process's
        ``sys.stdout``/``sys.stderr`` lines through ``print_line`` (restored on ``stop``), as rich's
        own Live does in-process
    """

    def __init__(
        self,
        telemetry: TelemetryBuffer,
        refresh_hz: float = 10.0,
        on_quit: Callable[[], None] | None = None,
        plain: bool | None = None,
        console: Console | None = None,
        *,
        window_s: float = 5.0,
        keys: bool | None = None,
        status_period_s: float = PLAIN_PERIOD_S,
        isolation: str = "auto",
        process_output: IO | None = None,
        process_size: tuple[int, int] | None = None,
        redirect_output: bool = True,
    ) -> None:
        if not (isinstance(refresh_hz, (int, float)) and math.isfinite(refresh_hz) and refresh_hz > 0):
            raise ValueError(f"dashboard refresh_hz must be a finite number > 0, got {refresh_hz!r}")
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"dashboard window_s must be a finite number > 0 [s], got {window_s!r}")
        if isolation not in ISOLATIONS:
            raise ValueError(f"dashboard isolation must be one of {ISOLATIONS}, got {isolation!r}")
        self.telemetry = telemetry
        self.refresh_hz = float(refresh_hz)
        self.on_quit = on_quit
        injected_console = console is not None
        self.console = console if console is not None else Console()
        self.plain = (not self.console.is_terminal) if plain is None else bool(plain)
        if self.plain:
            self.isolation = "thread"  # one short line per second: cheap enough to stay here
        elif isolation == "auto":
            self.isolation = "thread" if injected_console else "process"
        else:
            self.isolation = isolation
        self._process_output = process_output
        self._process_size = process_size
        self._process: subprocess.Popen | None = None
        self._redirect = redirect_output and self.isolation == "process" and process_output is None
        self._forwarders: list[_LineForwarder] = []
        self.window_s = float(window_s)
        if not (math.isfinite(status_period_s) and status_period_s > 0):
            raise ValueError(f"dashboard status_period_s must be a finite number > 0 [s], got {status_period_s!r}")
        self.status_period_s = float(status_period_s)
        self._want_keys = keys
        self._stop = threading.Event()
        self._paused = threading.Event()
        self._render_thread: threading.Thread | None = None
        self._key_thread: threading.Thread | None = None
        self._frames_lock = threading.Lock()
        self._messages: collections.deque[str] = collections.deque(maxlen=200)
        self.frames_rendered = 0  # Live frames drawn or status lines printed
        self.ticks = 0  # render-loop iterations (drawn or skipped while paused)
        self.render_errors = 0
        self.last_render_error = ""

    # ------------------------------------------------------------------ lifecycle

    @property
    def paused(self) -> bool:
        return self._paused.is_set()

    @property
    def draws_in_this_process(self) -> bool:
        """True when the Live view is drawn by a thread here (holding the interpreter lock for many control periods
        per frame): ``runtime_tuning.ProcessTuning`` then keeps the switch interval low while it runs."""
        return self.isolation == "thread" and not self.plain

    @property
    def running(self) -> bool:
        return self._render_thread is not None and self._render_thread.is_alive()

    def start(self) -> "DashboardRunner":
        """Start the render thread (and the key reader when stdin is a TTY). Returns self."""
        if self._render_thread is not None:
            raise RuntimeError("DashboardRunner already started")
        self._stop.clear()
        if self.plain:
            target = self._run_plain
        elif self.isolation == "process":
            self._process = self._spawn_renderer()
            target = self._run_feeder
        else:
            target = self._run_live
        self._render_thread = threading.Thread(target=target, name="mavastsm-dashboard", daemon=True)
        self._render_thread.start()
        if self._redirect:
            self._forwarders = [_LineForwarder(self.print_line, sys.stdout), _LineForwarder(self.print_line, sys.stderr)]
            sys.stdout, sys.stderr = self._forwarders
        if self._keys_enabled():
            self._key_thread = threading.Thread(target=read_keys, args=(self._stop, self.handle_key),
                                                name="mavastsm-dashboard-keys", daemon=True)
            self._key_thread.start()
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop rendering (draws one last frame), restore the terminal and the output streams."""
        self._restore_output()
        self._stop.set()
        for thread in (self._render_thread, self._key_thread):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout_s)
        self._render_thread = self._key_thread = None
        self._reap_renderer(timeout_s)

    def _restore_output(self) -> None:
        if not self._forwarders:
            return
        out, err = self._forwarders
        if sys.stdout is out:
            sys.stdout = out.original
        if sys.stderr is err:
            sys.stderr = err.original
        for forwarder in self._forwarders:
            forwarder.flush_partial()  # queued: the final frame prints it
        self._forwarders = []

    def __enter__(self) -> "DashboardRunner":
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ messages

    def print_line(self, text: str) -> None:
        """Show a one-off message (e.g. the bridge's ``print_fn`` status) above the Live view.

        Thread-safe and non-blocking. A plain ``print`` while the Live view is drawn (by the child
        process) would be overwritten by the next frame; this queues the text and the renderer prints
        it above the view at its next refresh. In plain mode, or when not running, it prints at once.
        """
        text = str(text)
        if self._forwarders and not self.running:  # drawing process gone: write past our own proxy
            try:
                original = self._forwarders[0].original
                original.write(text + "\n")
                original.flush()
            except Exception as exc:  # noqa: BLE001
                self._note_error(exc)
            return
        if self.plain or not self.running:
            try:
                self.console.print(text, markup=False, highlight=False, soft_wrap=True, emoji=False)
            except Exception as exc:  # noqa: BLE001
                self._note_error(exc)
            return
        self._messages.append(text)

    def _take_messages(self) -> tuple[str, ...]:
        out = []
        while self._messages:
            out.append(self._messages.popleft())
        return tuple(out)

    # ------------------------------------------------------------------ keys

    def handle_key(self, key: str) -> None:
        """React to one key: 'q' calls ``on_quit``; 'p' pauses/resumes rendering. Others ignored."""
        key = key.lower()
        if key == "q":
            if self.on_quit is not None:
                self.on_quit()
        elif key == "p":
            if self._paused.is_set():
                self._paused.clear()
            else:
                self._paused.set()

    def _keys_enabled(self) -> bool:
        if self._want_keys is not None:
            return self._want_keys
        try:
            return sys.stdin is not None and sys.stdin.isatty()
        except (ValueError, OSError):
            return False

    # ------------------------------------------------------------------ rendering

    def build_current_view(self, paused: bool | None = None):
        """The view for the current snapshot at the console's size (also used for screenshots)."""
        snapshot = self.telemetry.snapshot()
        width, height = self.console.size
        paused = self.paused if paused is None else paused
        return build_view(snapshot, width, height, paused=paused, window_s=self.window_s)

    def _count_frame(self) -> None:
        with self._frames_lock:
            self.frames_rendered += 1

    def _note_error(self, exc: BaseException) -> None:
        self.render_errors += 1
        self.last_render_error = f"{type(exc).__name__}: {exc}"

    def _run_live(self) -> None:
        period = 1.0 / self.refresh_hz
        try:
            live = Live(console=self.console, auto_refresh=False, transient=False,
                        redirect_stdout=False, redirect_stderr=False, vertical_overflow="crop")
            live.start()
        except Exception as exc:  # noqa: BLE001
            self._note_error(exc)
            return
        shown_paused = False
        try:
            next_t = time.monotonic()
            while not self._stop.is_set():
                self.ticks += 1
                paused = self.paused
                for message in self._take_messages():
                    live.console.print(message, markup=False, highlight=False, soft_wrap=True, emoji=False)
                if not paused or not shown_paused:  # draw once more to show PAUSED, then idle
                    try:
                        live.update(self.build_current_view(paused), refresh=True)
                        self._count_frame()
                    except Exception as exc:  # noqa: BLE001 - never propagate into the bridge
                        self._note_error(exc)
                    shown_paused = paused
                next_t += period
                delay = next_t - time.monotonic()
                if delay < 0:  # fell behind (loaded machine): skip, do not catch up in a burst
                    next_t = time.monotonic()
                    delay = 0.0
                self._stop.wait(delay)
            try:
                for message in self._take_messages():
                    live.console.print(message, markup=False, highlight=False, soft_wrap=True, emoji=False)
                live.update(self.build_current_view(), refresh=True)
                self._count_frame()
            except Exception as exc:  # noqa: BLE001
                self._note_error(exc)
        finally:
            try:
                live.stop()
            except Exception as exc:  # noqa: BLE001
                self._note_error(exc)

    # ------------------------------------------------------------------ child-process rendering

    def _spawn_renderer(self) -> subprocess.Popen:
        """Start the drawing process at the lowest CPU priority (Linux ``SCHED_IDLE``, else nice
        +``RENDER_NICENESS``; set before its imports) so that on a busy machine it only gets CPU time
        the bridge and the vehicle leave over: under overload the view lags, the loop does not."""
        args = ["--capacity", str(self.telemetry.capacity), "--window-s", repr(self.window_s)]
        if self._process_size is not None:
            args += ["--width", str(self._process_size[0]), "--height", str(self._process_size[1]),
                     "--force-terminal", "--no-color"]
        launcher = ("import os, sys\n"
                    "try: os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))\n"
                    f"except (AttributeError, OSError):\n    try: os.nice({RENDER_NICENESS})\n"
                    "    except OSError: pass\n"
                    "from mavastsm.dashboard.render_process import main\n"
                    "sys.exit(main(sys.argv[1:]))\n")
        env = dict(os.environ)
        package_root = str(Path(__file__).resolve().parents[2])  # works from a source checkout too
        env["PYTHONPATH"] = package_root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        return subprocess.Popen([sys.executable, "-c", launcher, *args], stdin=subprocess.PIPE,
                                stdout=self._process_output, env=env, close_fds=True)

    def _run_feeder(self) -> None:
        """Forward new samples to the drawing process at ``refresh_hz``. Blocking writes only
        block this thread (the pipe write releases the interpreter lock), never the control loop."""
        proc = self._process
        assert proc is not None and proc.stdin is not None
        period = 1.0 / self.refresh_hz
        cursor = 0
        last_link = last_session = None
        shown_paused = False
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                self.ticks += 1
                paused = self.paused
                if not paused or not shown_paused or self._messages:
                    cursor, samples = self.telemetry.samples_since(cursor)
                    link, session = self.telemetry.link, self.telemetry.session
                    self._send_update(proc.stdin, samples, None if link is last_link else link,
                                      None if session is last_session else session, paused)
                    last_link, last_session = link, session
                    self._count_frame()
                    shown_paused = paused
                next_t += period
                delay = next_t - time.monotonic()
                if delay < 0:
                    next_t, delay = time.monotonic(), 0.0
                self._stop.wait(delay)
            cursor, samples = self.telemetry.samples_since(cursor)
            self._send_update(proc.stdin, samples, self.telemetry.link, self.telemetry.session, self.paused)
            pickle.dump(("stop", None), proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            proc.stdin.flush()
            self._count_frame()
        except (OSError, ValueError) as exc:  # child gone (BrokenPipe) or pipe closed
            self._note_error(exc)
        except Exception as exc:  # noqa: BLE001 - never propagate into the bridge
            self._note_error(exc)
        finally:
            try:
                proc.stdin.close()
            except OSError:
                pass

    def _send_update(self, pipe, samples, link, session, paused: bool) -> None:
        """Pickle in small chunks (each ``pickle.dump`` holds the interpreter lock for its whole
        duration); only the last chunk asks the child to draw."""
        samples = samples[-MAX_SAMPLES_PER_UPDATE:]
        starts = range(0, max(1, len(samples)), PICKLE_CHUNK_SAMPLES)
        for i, start in enumerate(starts):
            last = i == len(starts) - 1
            update = FrameUpdate(samples[start:start + PICKLE_CHUNK_SAMPLES], link if last else None,
                                 session if last else None, self.telemetry.active_failsafe, paused, draw=last,
                                 messages=self._take_messages() if last else ())
            pickle.dump(("frame", update), pipe, protocol=pickle.HIGHEST_PROTOCOL)
        pipe.flush()

    def _reap_renderer(self, timeout_s: float) -> None:
        proc, self._process = self._process, None
        if proc is None:
            return
        try:
            if proc.stdin is not None and not proc.stdin.closed:
                proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.terminate()
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    # ------------------------------------------------------------------ plain lines

    def _run_plain(self) -> None:
        period = self.status_period_s
        next_t = time.monotonic() + period
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            self.ticks += 1
            next_t += period
            if next_t < time.monotonic():
                next_t = time.monotonic() + period
            if self.paused:
                continue
            self._print_status_line()
        self._print_status_line()

    def _print_status_line(self) -> None:
        try:
            line = format_status_line(self.telemetry.snapshot(max_samples=1))
            self.console.print(line, markup=False, highlight=False, soft_wrap=True, emoji=False)
            self.console.file.flush()
            self._count_frame()
        except Exception as exc:  # noqa: BLE001
            self._note_error(exc)
