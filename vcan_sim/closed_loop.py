"""Closed loop: the MDPS side of ``LDE_Overlay``. Received frames pass the E2E Profile 1 check
(:class:`lde.can.e2e.P01Receiver`: CRC, counter sequence, MaxDeltaCounter, re-synchronisation after
faults) before their ``OverlayTorque`` is applied; ``Active = 0`` requests zero.

When the request is not trustworthy (no frame within the message timeout, receiver not trusted
after a fault) the MDPS does not step: the request ramps to zero at ``ramp_rate`` [Nm/s]. The
applied torque is further clamped and lagged inside the plant (:mod:`vcan_sim.steering`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import can

from lde.can.busio import drain
from lde.can.codec import MessageCodec
from lde.can.e2e import E2EStatus, P01Receiver
from lde.can.profiles import Profile

from .emitter import to_messages


@dataclass
class OverlayStats:
    """Counts: frames with the overlay id, frames whose value was used, rejected by E2E, wrong length."""

    received: int = 0
    used: int = 0
    rejected: int = 0
    malformed: int = 0


class OverlayReceiver:
    """Turns received ``LDE_Overlay`` frames into the overlay-torque request [Nm, left positive]."""

    def __init__(self, profile: Profile, ramp_rate: float = 5.0) -> None:
        self.spec = profile.spec("LDE_Overlay")
        self.codec = MessageCodec(profile, "LDE_Overlay")
        assert self.spec.receiver is not None  # lde's outputs always have their timeout
        self.e2e = P01Receiver(self.spec.receiver, data_id=self.spec.frame_id, scheme=self.spec.scheme)
        self.ramp_rate = float(ramp_rate)
        self.stats = OverlayStats()
        self._value = 0.0  # last accepted request [Nm]
        self._out = 0.0  # request handed to the plant [Nm]
        self._t_last: int | None = None

    def on_message(self, msg: can.Message, t_ns: int) -> E2EStatus | None:
        """Feed one received frame (any id) at simulated time ``t_ns``; status if it was an overlay frame."""
        if msg.is_error_frame or msg.is_remote_frame or msg.arbitration_id != self.spec.frame_id:
            return None
        self.stats.received += 1
        data = bytes(msg.data)
        if len(data) != self.spec.length:
            self.stats.malformed += 1
            return None
        status = self.e2e.receive_frame(int(t_ns), data)
        if self.e2e.accepted and self.e2e.trusted:
            vals = self.codec.decode(data)
            self._value = float(vals["OverlayTorque"]) if vals.get("Active", 0.0) >= 0.5 else 0.0
            self.stats.used += 1
        elif status in (E2EStatus.REPEATED, E2EStatus.WRONGSEQUENCE, E2EStatus.WRONGCRC):
            self.stats.rejected += 1
        return status

    def valid(self, t_ns: int) -> bool:
        """True if the last request may be applied at ``t_ns``."""
        return self.e2e.trusted and not self.e2e.timed_out(int(t_ns))

    def request(self, t_ns: int) -> float:
        """The overlay request at ``t_ns`` [Nm]: the received value, or a ramp to 0 when not valid."""
        dt = 0.0 if self._t_last is None else max(0.0, (int(t_ns) - self._t_last) * 1e-9)
        self._t_last = int(t_ns)
        if self.valid(t_ns):
            self._out = self._value
        else:
            step = self.ramp_rate * dt
            self._out = max(0.0, self._out - step) if self._out > 0 else min(0.0, self._out + step)
        return self._out


@dataclass
class LockstepStats:
    """Frames sent to the bus, overlay frames taken in, steps run."""

    sent: int = 0
    overlay_frames: int = 0
    steps: int = 0


def run_lockstep(
    sim,
    bus: can.BusABC,
    receiver: OverlayReceiver,
    service_step: Callable[[int], object],
    latency_ns: int = 200_000,
) -> LockstepStats:
    """Deterministic closed loop on one bus, without wall-clock time (tests, the demo).

    Per 3.9 ms period: the simulation steps with the current overlay request, its frames go on
    ``bus`` with their simulated timestamps (open a python-can virtual bus with
    ``preserve_timestamps=True``), ``service_step(t_k)`` runs the service under test at
    ``t_k`` = period start + ``latency_ns`` (so it sees this period's MDPS frame), and every frame
    it sent back is fed to ``receiver`` at its timestamp. The overlay therefore acts one period
    after the frame it was computed from, like on a real bus.
    """
    st = LockstepStats()
    while not sim.done:
        t_start = sim.t_ns
        frames = sim.step(receiver.request(t_start))
        for msg in to_messages(frames):
            bus.send(msg)
            st.sent += 1
        service_step(t_start + latency_ns)
        st.steps += 1
        for back in drain(bus):
            t_rx = int(round(back.timestamp * 1e9)) if back.timestamp else t_start + latency_ns
            if receiver.on_message(back, t_rx) is not None:
                st.overlay_frames += 1
    return st
