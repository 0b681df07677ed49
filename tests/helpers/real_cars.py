"""The real cars' logs the repository ships: ``tests/data/real``, each with its licence notice."""

from __future__ import annotations

from helpers import TESTS

#: the folder of the real logs and their licence notices
REAL = TESTS / "data" / "real"
#: a Toyota RAV4 2017 driving 60 s (comma2k19, MIT): bus can0 holds the profile's messages
RAV4_LOG = REAL / "rav4_2017_highway.log.gz"
#: a Hyundai Kona EV standing still (CC0)
KONA_LOG = REAL / "kona_ev_2019_standstill.log.gz"
