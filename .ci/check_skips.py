"""Fail on a skipped test whose reason is not on the checked-in allow-list.

A skip can hide a missing install step or an undeclared dependency as well as a genuinely absent
piece of the machine (no SocketCAN in the host kernel, ...). This reads pytest's JUnit XML report,
matches every skip's reason against the patterns of ``.ci/allowed-skips.txt`` (Python regular
expressions, ``re.search``; one a line, ``#`` comments) and exits 1 if a reason matches none, or if
the report holds no executed test.

``tests/test_uml.py`` reports the skips of the tests it runs inside user-mode Linux as one skip,
"N skip(s) inside user-mode Linux (T s): R1 || R2 ..."; each of those reasons must be allowed on
its own.

usage: python .ci/check_skips.py REPORT.xml [--allow .ci/allowed-skips.txt]
"""

from __future__ import annotations

import argparse
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ALLOW = Path(__file__).with_name("allowed-skips.txt")
#: tests/test_uml.py's summary of the skips inside the guest
GUEST_SKIPS = re.compile(r"^\d+ skip\(s\) inside user-mode Linux \([^)]*\): (?P<reasons>.*)$", re.S)


def allowed_patterns(path: Path) -> list[re.Pattern[str]]:
    out = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            out.append(re.compile(line))
        except re.error as exc:
            sys.exit(f"{path}:{n}: not a regular expression: {exc}")
    return out


def skips(report: Path) -> tuple[int, list[tuple[str, str]]]:
    """(number of test cases, [(test id, skip reason)]) of a pytest JUnit XML report."""
    root = ET.parse(report).getroot()
    cases = list(root.iter("testcase"))
    out = []
    for case in cases:
        for sk in case.findall("skipped"):
            test = f"{case.get('classname', '')}::{case.get('name', '')}"
            out.append((test, sk.get("message") or sk.text or ""))
    return len(cases), out


def reasons_of(reason: str) -> list[str]:
    """The reasons to check: the guest's own for tests/test_uml.py's summary, else the reason."""
    m = GUEST_SKIPS.match(reason)
    return [r.strip() for r in m.group("reasons").split(" || ")] if m else [reason]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="pytest --junitxml report")
    ap.add_argument("--allow", type=Path, default=ALLOW, help="allow-list (default: %(default)s)")
    a = ap.parse_args()
    if not a.report.is_file():
        print(f"check_skips: no report {a.report} (did pytest run?)", file=sys.stderr)
        return 1
    patterns = allowed_patterns(a.allow)
    n_cases, found = skips(a.report)
    bad: list[tuple[str, str]] = []
    n_allowed = 0
    for test, reason in found:
        for r in reasons_of(reason):
            if any(p.search(r) for p in patterns):
                n_allowed += 1
            else:
                bad.append((test, r))
    if n_cases - len(found) <= 0:
        print(f"check_skips: {n_cases} test cases, none executed", file=sys.stderr)
        return 1
    print(f"check_skips: {len(found)} skipped of {n_cases}; {n_allowed} skip reason(s) on {a.allow.name}")
    for test, r in bad:
        print(f"check_skips: NOT ALLOWED: {test}: {r}", file=sys.stderr)
    if bad:
        print(
            f"check_skips: {len(bad)} skip reason(s) not on {a.allow}: declare what the test needs, or,"
            " if the machine genuinely lacks it, add the reason there with why",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
