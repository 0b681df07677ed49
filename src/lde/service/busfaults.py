"""Live bus faults, said once: a line when a fault starts, a slow reminder while it lasts, a line when
it clears.

The service counts what goes wrong on its bus (failed sends and receives, error frames, E2E
rejections per input message, foreign frames) and, every 0.25 s, hands :class:`BusFaults` the counts
of that window. Each fault class is a :class:`FaultTracker`: active while its window count is
non-zero (or above a rate), cleared after ``clear_ns`` without it; it returns the lines to log. The
counts themselves are the service's (``Service.send_errors`` and friends, never reset).

Pure logic: times are passed in [ns]; nothing here reads a clock or a bus.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

__all__ = [
    "REPEAT_NS",
    "FLOOD_FOREIGN_HZ",
    "OTHER_SENDER_RATE",
    "BusFaults",
    "E2EWindow",
    "FaultTracker",
    "WindowCounts",
    "describe_error_frame",
]

#: while a fault lasts, its warning is repeated this often [ns] (a log, not a flood)
REPEAT_NS = 30 * 10**9
#: error frames and E2E rejections are cleared after this long without one [ns]
QUIET_NS = 1_000_000_000
#: frames of other messages on the bus above this rate [1/s] are reported as a flood. A classic CAN
#: bus at 500 kbit/s carries at most ~4400 frames/s in all; a car bus shared with other ECUs can carry
#: well over 1000/s of other traffic, so raise it there (``Service(flood_hz=...)``).
FLOOD_FOREIGN_HZ = 2000.0
#: a message that was healthy and now fails its E2E checks while arriving at least this many times as
#: often as its period says is reported as coming from a second sender (two ECUs, or two simulators
#: on one udp_multicast group and port, each with its own counter). A second sender that starts late
#: in a check window may show this rate only in the next one: its E2E line then comes first.
OTHER_SENDER_RATE = 1.25

# SocketCAN error frame classes (linux/can/error.h, bits of the can_id)
_ERR_CLASSES = (
    (0x001, "tx timeout"),
    (0x002, "lost arbitration"),
    (0x004, "controller problem"),
    (0x008, "protocol violation"),
    (0x010, "transceiver status"),
    (0x020, "no ack"),
    (0x040, "bus-off"),
    (0x080, "bus error"),
    (0x100, "controller restarted"),
    (0x200, "error counters"),
)


def describe_error_frame(can_id: int) -> str:
    """The error classes of an error frame's id ("bus-off, no ack"), or "unspecified"."""
    names = [name for bit, name in _ERR_CLASSES if can_id & bit]
    return ", ".join(names) or "unspecified"


@dataclass
class FaultTracker:
    """One fault class.

    Args:
        name: what is reported ("CAN send", "error frames", "E2E MDPS_Sensors (0x2A0)").
        clear_ns: the fault clears after this long without it [ns] (0: at the first clean window).
        repeat_ns: repeat period of the warning while it lasts [ns].
    """

    name: str
    clear_ns: int = 0
    repeat_ns: int = REPEAT_NS
    sep: str = ": "  # between the name and the rest of its lines
    since_ns: int | None = None  # start of the current fault, None when clear
    last_ns: int = 0  # time of the last window with the fault [ns]
    count: int = 0  # events in the current fault
    episodes: int = 0  # faults started so far
    _next_warn_ns: int = 0

    @property
    def active(self) -> bool:
        return self.since_ns is not None

    def update(self, t_ns: int, events: int, detail: str = "", ok: bool = True) -> list[tuple[str, str]]:
        """The window ending at ``t_ns`` [ns] had ``events`` events (``detail`` says what); ``ok``:
        the window also shows the thing working (a send that went out, an accepted frame), which
        a clear needs. Returns the lines to log as (level, text), level "warning" or "info"."""
        lines: list[tuple[str, str]] = []
        if events > 0:
            self.last_ns = t_ns
            if self.since_ns is None:
                self.since_ns = t_ns
                self.count = events
                self.episodes += 1
                self._next_warn_ns = t_ns + self.repeat_ns
                lines.append(("warning", f"{self.name}{self.sep}{detail}"))
            else:
                self.count += events
                if t_ns >= self._next_warn_ns:
                    self._next_warn_ns = t_ns + self.repeat_ns
                    lines.append(
                        (
                            "warning",
                            f"{self.name}{self.sep}still, for {(t_ns - self.since_ns) * 1e-9:.1f} s"
                            f" ({self.count} in all): {detail}",
                        )
                    )
        elif self.since_ns is not None and ok and t_ns - self.last_ns >= self.clear_ns:
            lasted = (self.last_ns - self.since_ns) * 1e-9
            lines.append(
                (
                    "info",
                    f"{self.name}{self.sep}cleared after {lasted:.2f} s ({self.count} in all)",
                )
            )
            self.since_ns = None
        return lines


class E2EWindow(NamedTuple):
    """One input message in a check window: ``label`` ("MDPS_Sensors (0x2A0)"), frames ``rejected``
    by E2E and ``used``, ``what`` the rejections were; ``received`` its frames in the window and
    ``expected`` how many its period gives (0: not known)."""

    label: str
    rejected: int
    used: int
    what: str
    received: int = 0
    expected: float = 0.0


@dataclass(frozen=True)
class WindowCounts:
    """What the service counted in one check window (since the previous check).

    Attributes:
        t_ns: end of the window (step time) [ns].
        span_ns: its length [ns].
        send_errors: sends the bus refused; ``sent``: sends it took.
        recv_errors: receive calls that raised; ``received``: frames received (any id).
        error_frames: error frames received; ``error_id``: the last one's id (its classes).
        foreign: frames of other messages that reached the service.
        bus_frames: frames the interface counted (SocketCAN ``rx_packets``), -1 when unknown.
        own_frames: frames of the profile on the bus in the window (inputs received + outputs sent).
        e2e: per input message, :class:`E2EWindow` (or a tuple of its fields).
        send_error, recv_error: the text of the last failed send / receive.
    """

    t_ns: int
    span_ns: int
    send_errors: int = 0
    sent: int = 0
    recv_errors: int = 0
    received: int = 0
    error_frames: int = 0
    error_id: int = 0
    foreign: int = 0
    bus_frames: int = -1
    own_frames: int = 0
    e2e: tuple[E2EWindow | tuple, ...] = ()
    send_error: str = ""
    recv_error: str = ""


@dataclass
class BusFaults:
    """The service's fault trackers (module docstring) for the bus ``where`` ("socketcan channel
    'vcan0'"); ``flood_hz``: the foreign-frame rate reported as a flood [1/s]."""

    where: str
    flood_hz: float = FLOOD_FOREIGN_HZ
    send: FaultTracker = field(init=False)
    recv: FaultTracker = field(init=False)
    errors: FaultTracker = field(init=False)
    flood: FaultTracker = field(init=False)
    e2e: dict[str, FaultTracker] = field(default_factory=dict)
    #: per input message: a second sender (:data:`OTHER_SENDER_RATE`)
    others: dict[str, FaultTracker] = field(default_factory=dict)
    #: messages with a clean window (frames used, none rejected) since their last E2E episode
    _healthy: set[str] = field(default_factory=set, init=False, repr=False)
    #: per message: whether its current (or last) E2E episode began on a healthy message
    _from_healthy: dict[str, bool] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        self.send = FaultTracker("CAN send failing")
        self.recv = FaultTracker("CAN receive failing")
        self.errors = FaultTracker(f"error frames on {self.where}", clear_ns=QUIET_NS)
        self.flood = FaultTracker(f"foreign frames flood {self.where}", clear_ns=QUIET_NS)

    def trackers(self) -> list[FaultTracker]:
        return [self.send, self.recv, self.errors, self.flood, *self.e2e.values(), *self.others.values()]

    @property
    def active(self) -> list[str]:
        """Names of the faults active now."""
        return [t.name for t in self.trackers() if t.active]

    def check(self, w: WindowCounts) -> list[tuple[str, str]]:
        """Lines to log for the window ``w`` (level, text)."""
        out: list[tuple[str, str]] = []
        out += self.send.update(
            w.t_ns,
            w.send_errors,
            f"{w.send_errors} frames not sent in {w.span_ns * 1e-9:.2f} s on {self.where} ({w.send_error});"
            " the outputs do not reach the bus (the MDPS times the overlay out); the loop keeps stepping",
            ok=w.sent > 0,
        )
        out += self.recv.update(
            w.t_ns,
            w.recv_errors,
            f"{w.recv_errors} failed receive calls on {self.where} ({w.recv_error}); the loop keeps stepping",
            ok=w.received > 0,
        )
        out += self.errors.update(
            w.t_ns,
            w.error_frames,
            f"{w.error_frames} in {w.span_ns * 1e-9:.2f} s (last: 0x{w.error_id:X}:"
            f" {describe_error_frame(w.error_id)}); inputs are still used while their E2E checks pass",
        )
        rate, how = self._foreign_rate(w)
        flood = rate > self.flood_hz
        out += self.flood.update(
            w.t_ns,
            int(rate * w.span_ns * 1e-9) if flood else 0,
            f"{rate:.0f} foreign frames/s ({how}); {w.foreign} reached the service in"
            f" {w.span_ns * 1e-9:.2f} s (the input filters keep the others out)",
        )
        for entry in w.e2e:
            out += self._check_e2e(w, E2EWindow(*entry))
        return out

    def _check_e2e(self, w: WindowCounts, e: E2EWindow) -> list[tuple[str, str]]:
        """One input message's E2E rejections; a burst of them on a message that was healthy, while
        it arrives more often than its period says, is said as another sender on the bus (once,
        instead of the E2E line)."""
        tr = self.e2e.get(e.label)
        if tr is None:
            tr = self.e2e[e.label] = FaultTracker(f"E2E {e.label}", clear_ns=QUIET_NS)
        other = self.others.get(e.label)
        if other is None:
            other = self.others[e.label] = FaultTracker(
                f"another sender on this bus ({self.where})?", clear_ns=QUIET_NS, sep=" "
            )
        if e.rejected > 0 and not tr.active:  # an E2E episode starts: was the message healthy?
            self._from_healthy[e.label] = e.label in self._healthy
            self._healthy.discard(e.label)
        doubled = e.expected > 0 and e.received >= OTHER_SENDER_RATE * e.expected
        suspect = e.rejected > 0 and doubled and self._from_healthy.get(e.label, False)
        said = other.update(
            w.t_ns,
            e.rejected if suspect else 0,
            f"{e.label} arrives {e.received / e.expected if e.expected else 0:.1f}x as often as its period"
            f" says ({e.received} frames in {w.span_ns * 1e-9:.2f} s, {e.expected:.0f} expected) and"
            f" {e.rejected} of them fail the E2E check ({e.what}): a second node sends it too. On"
            " udp_multicast: another program on this host uses the same group and port; give each"
            " bus a group and port of its own (docs/service.md, 'The bus')",
            ok=e.used > 0,
        )
        lines = tr.update(
            w.t_ns,
            e.rejected,
            f"{e.rejected} frames rejected ({e.what}); the input is re-synchronised before it is used",
            ok=e.used > 0,
        )
        if e.rejected == 0 and e.used > 0 and not tr.active:
            self._healthy.add(e.label)
        if any(level == "warning" for level, _ in said):  # one warning for the burst: the likely cause
            lines = [ln for ln in lines if ln[0] != "warning"]
        return said + lines

    @staticmethod
    def _foreign_rate(w: WindowCounts) -> tuple[float, str]:
        """Foreign frames per second in the window: from the interface's counter where known (what
        the kernel filters dropped included), else what reached the service."""
        span_s = max(w.span_ns, 1) * 1e-9
        if w.bus_frames >= 0:
            return max(0, w.bus_frames - w.own_frames) / span_s, "the interface's frame counter"
        return w.foreign / span_s, "frames that reached the service"
