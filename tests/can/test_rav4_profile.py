"""The shipped toyota_rav4_2017 profile on the real car's drive (``shared/real/README.md``): the log
decodes, every STEER_TORQUE_SENSOR frame passes Toyota's checksum, the inputs come from bus 0 only and
lie in the drive's physical ranges. The signs are not checked here (``lde inspect`` finds them)."""

from __future__ import annotations

import numpy as np
import pytest

from lde.can.e2e import toyota_checksum
from lde.can.profiles import load_profile
from lde.engine.receiver import decode_batch
from lde.io import read_log
from lde.units import DEG, KMH

from helpers.real_cars import RAV4_LOG

LOG = RAV4_LOG


@pytest.fixture(scope="module")
def frames():
    return read_log(LOG).frames


def test_every_steer_torque_frame_passes_toyotas_checksum(frames):
    t = frames.select((frames.can_id == 0x260) & ~frames.is_extended)
    assert len(t) == 3000 and set(t.channel_names().tolist()) == {"can0"}
    ok = [
        toyota_checksum(0x260, t.data[i, : t.dlc[i]].tobytes()) == t.data[i, t.dlc[i] - 1]
        for i in range(len(t))
    ]
    assert all(ok)


def test_the_log_decodes_with_the_shipped_profile(frames):
    p = load_profile("toyota_rav4_2017")
    assert not p.torque_scales_known and p.absent == frozenset()
    assert set(frames.channels) == {"can0", "can1"}
    d = decode_batch(p, frames)
    for name, m in d.messages.items():
        s = m.stats
        assert s.rejected == 0 and s.malformed == 0 and s.used >= s.received - 2, (name, s)
    assert d.other_bus == 0
    speed = d.inputs["speed"].value / KMH
    assert speed.min() > 25.0 and speed.max() < 75.0  # README: 28-72 km/h
    angle = d.inputs["steering_angle"].value / DEG
    assert np.abs(angle).max() <= 6.0  # README: |steering angle| <= 5 deg
    # the fraction adds resolution below STEER_ANGLE's 1.5 deg steps
    assert len(np.unique(np.round(angle, 3))) > len(np.unique(np.round(angle / 1.5)))
    assert np.abs(d.inputs["yaw_rate"].value).max() < 0.2  # rad/s: gentle highway driving
    assert np.abs(d.inputs["lat_accel"].value).max() < 3.0  # m/s^2
    assert np.abs(d.inputs["column_torque"].value).max() > 0  # raw counts, moving
