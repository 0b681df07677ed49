"""Import every module of the product in a plain install (no extras): each must import, and none
may pull in a module that only an extra provides.

Two modules need an extra and are left out on purpose; the check then asserts that no other module
imported them:
  lde.kalman_reference   the filterpy reference the float filter is tested against ([test])
  lde.testing.plugin     lde's pytest plugin, loaded by pytest itself through its pytest11 entry point

usage: python .ci/import_product.py   (in the plain install's environment, from any directory)
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import traceback

PACKAGES = ("lde", "firmware_model", "vcan_sim")
EXTRA_ONLY = {"lde.kalman_reference": "filterpy", "lde.testing.plugin": "pytest"}


def main() -> int:
    failed: list[str] = []
    names: list[str] = []
    for pkg in PACKAGES:
        mod = importlib.import_module(pkg)
        names.append(pkg)
        for info in pkgutil.walk_packages(mod.__path__, prefix=f"{pkg}."):
            if info.name in EXTRA_ONLY or info.name.rsplit(".", 1)[-1] == "__main__":
                continue
            try:
                importlib.import_module(info.name)
            except Exception:
                failed.append(f"{info.name}:\n{traceback.format_exc(limit=3)}")
            names.append(info.name)
    for name, dist in EXTRA_ONLY.items():
        if name in sys.modules:
            failed.append(f"{name} (needs {dist}, an extra) was imported by another product module")
        if dist in sys.modules:
            failed.append(f"{dist} (an extra's package) was imported by a product module")
    print(f"import_product: {len(names)} product modules tried, {len(failed)} problem(s)", end="; ")
    print(f"left out: {', '.join(EXTRA_ONLY)}")
    for f in failed:
        print(f"FAILED {f}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
