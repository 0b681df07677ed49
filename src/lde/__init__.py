"""lde: lateral disturbance estimator for cars with motor-driven power steering.

Data path, the same live and in replay (see docs/ARCHITECTURE.md):
frames -> signals (decode by profile, E2E receiver) -> inputs in SI on the 3.9 ms grid
-> estimator step (float or fixed backend) -> estimate -> overlay law + limiter -> output frames.
"""

from lde.errors import BusError, ConfigError, LdeError, LogFormatError

__version__ = "0.1.0"
__all__ = ["LdeError", "ConfigError", "LogFormatError", "BusError", "__version__"]
