"""One inspection of a log: the survey, the profile fit, the inputs and the physics checks.

:func:`inspect_frames` runs the pieces of this package in order and returns an
:class:`Inspection` (plain data: :mod:`lde.analysis.inspect.report` prints it as text or JSON).
The profile checked is the one given; without one, the shipped profile that fits the log (all its
input messages on one channel with their lengths), if any does.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from lde.analysis.inspect.checks import Check, Geometry, SignFinding, attribute_signs, run_checks, with_fixes
from lde.analysis.inspect.inputs import ProfileInputs, decode_inputs
from lde.analysis.inspect.match import ProfileMatch, Wanted, match_profile, rank
from lde.analysis.inspect.resample import common_grid
from lde.analysis.inspect.survey import LogSurvey, survey_log
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile
from lde.params import Vehicle

__all__ = ["Inspection", "inspect_frames", "wanted"]


@dataclass(frozen=True)
class Inspection:
    """Everything ``lde inspect`` found (see the package modules for each part).

    Attributes:
        survey: the log's ids per channel.
        matches: every candidate profile's fit, best first.
        profile: the name of the profile checked (None: none given and none fits).
        profile_origin: ``given`` or ``shipped`` (the best fit).
        channel: the channel its messages were read from.
        names: id -> message name in the checked profile's DBC.
        inputs: the inputs' decode (None without a profile, or when none of its messages arrives).
        checks: the physics checks; signs: what they say of each input's sign.
        geometry: the vehicle figures the checks used; vehicle: the vehicle file's name.
        input_signs: each input's sign in the profile now.
    """

    survey: LogSurvey
    matches: tuple[ProfileMatch, ...]
    profile: str | None = None
    profile_origin: str = ""
    channel: str | None = None
    names: Mapping[int, str] = field(default_factory=dict)
    inputs: ProfileInputs | None = None
    checks: tuple[Check, ...] = ()
    signs: Mapping[str, SignFinding] = field(default_factory=dict)
    geometry: Geometry | None = None
    vehicle: str = ""
    input_signs: Mapping[str, float] = field(default_factory=dict)

    @property
    def checked(self) -> ProfileMatch | None:
        """The fit of the profile checked."""
        return next((m for m in self.matches if m.profile == self.profile), None)

    @property
    def no_input_messages(self) -> bool:
        """The log has none of the checked (or, without one, of any candidate) profile's input messages."""
        m = self.checked
        if m is not None:
            return m.present == 0
        return all(x.present == 0 for x in self.matches)


def wanted(profile: Profile, channels: tuple[str, ...] = ()) -> list[Wanted]:
    """A profile's input messages as :func:`lde.analysis.inspect.match.match_profile` wants them:
    on the bus the profile names for each, except in a log of one bus (whatever its name: that bus
    is the profile's, as :class:`lde.can.channels.ChannelSelect` takes it)."""
    one_bus = len(channels) <= 1
    return [
        Wanted(m.name, m.frame_id, m.length, None if one_bus else m.channel)
        for m in profile.messages.values()
    ]


def _on_channel(frames: FrameBatch, channel: str | None) -> FrameBatch:
    """The frames of one channel (all of them in a log of one bus)."""
    if channel is None or len(frames.channels) <= 1 or channel not in frames.channels:
        return frames
    return frames.select(frames.channel == frames.channels.index(channel))


def inspect_frames(
    frames: FrameBatch,
    vehicle: Vehicle,
    *,
    given: Profile | None = None,
    shipped: Sequence[Profile] = (),
) -> Inspection:
    """Inspect a log's frames (module doc): ``given`` the user's profile (checked whether it fits
    or not), ``shipped`` the profiles to rank beside it."""
    survey = survey_log(
        frames.t_ns, frames.can_id, frames.is_extended, frames.dlc, frames.channel, frames.channels
    )
    cands = [(p, "shipped") for p in shipped if given is None or p.name != given.name]
    if given is not None:
        cands.insert(0, (given, "given"))
    matches = rank([match_profile(survey, p.name, wanted(p, survey.channels), origin) for p, origin in cands])
    if given is not None:
        profile, origin = given, "given"
    else:
        best = next((m for m in matches if m.fits), None)
        if best is None:
            return Inspection(survey, tuple(matches))
        profile, origin = next(p for p, _ in cands if p.name == best.profile), "shipped"
    match = next(m for m in matches if m.profile == profile.name)
    names = {int(m.frame_id): m.name for m in profile.db.messages}
    base = Inspection(
        survey,
        tuple(matches),
        profile=profile.name,
        profile_origin=origin,
        channel=match.channel,
        names=names,
        vehicle=vehicle.name,
        geometry=Geometry.of(vehicle),
        input_signs={n: float(im.sign) for n, im in profile.inputs.items()},
    )
    if match.present == 0:
        return base
    inputs = decode_inputs(_on_channel(frames, match.channel), profile)
    grid = common_grid(inputs.series)
    units = {n: ("counts" if n in inputs.unknown_scale else "Nm") for n in ("column_torque", "assist_torque")}
    checks = run_checks(
        grid,
        base.geometry or Geometry.of(vehicle),
        torque_units=units,
        speed_is_wheels=inputs.speed_is_wheels,
        rate_signed=profile.steering_rate_signed,
    )
    signs = attribute_signs(checks)
    checks = with_fixes(checks, signs, base.input_signs)
    return Inspection(
        survey,
        tuple(matches),
        profile=profile.name,
        profile_origin=origin,
        channel=match.channel,
        names=names,
        inputs=inputs,
        checks=tuple(checks),
        signs=signs,
        geometry=base.geometry,
        vehicle=vehicle.name,
        input_signs=base.input_signs,
    )
