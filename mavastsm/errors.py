"""Package exceptions. Each subclasses a built-in so callers may catch either.

These are raised at start-up only (bad config, bad options, link not found). Inside the
control loop nothing raises: problems become a `FailsafeReason` (see `state_types`).
"""


class ConfigError(ValueError):
    """A configuration file or option is missing, malformed or breaks a rule.

    The message is one line naming the file, the key, the value and the rule broken.
    """


class Interrupted(RuntimeError):
    """The operator (Ctrl-C, SIGTERM, ``request_stop()``) ended a start-up wait before anything was flown.

    The message says what was being waited for and for how long; the command line exits 130 with it.
    """


class LinkError(ConnectionError):
    """The MAVLink link could not be opened, or no autopilot answered on it."""


class OffboardRejected(RuntimeError):
    """The autopilot refused a command needed to start offboard control (mode, arm, interval).

    Attributes
    ----------
    request : str
        What was asked, e.g. ``"COMMAND_LONG DO_SET_MODE GUIDED"``.
    result : int | None
        The MAV_RESULT from COMMAND_ACK, or None when no ACK came before the timeout (``failed`` then says
        what went wrong instead, e.g. "stopped" or "did not reach the altitude").
    """

    def __init__(self, request: str, result: int | None, detail: str = "", *, failed: str = "no COMMAND_ACK (timeout)") -> None:
        self.request = request
        self.result = result
        self.detail = detail
        what = failed if result is None else f"MAV_RESULT {result}"
        super().__init__(f"{request}: {what}" + (f" ({detail})" if detail else ""))
