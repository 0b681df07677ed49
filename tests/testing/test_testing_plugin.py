"""lde's pytest plugin (lde.testing.plugin), run on generated test files through pytester."""

from __future__ import annotations

import pytest

# pytester's inline runs give sys.modules back as it was before them: the bench and what it imports
# (numpy cannot be imported twice in one process) are imported here, before any inline run
import lde.testing.bench  # noqa: F401
from lde.testing import socketcan_unavailable

PLUGIN = ("-p", "lde.testing.plugin")  # the entry point has this name: harmless when it is installed


def test_each_test_gets_a_fresh_channel_closed_afterwards(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        from can.interfaces import virtual

        SEEN = []

        def test_a(lde_bench, lde_bus):
            SEEN.append(lde_bench.channel)
            assert lde_bus.channel_info.endswith(": test")
            assert lde_bench.channel in virtual.channels

        def test_b(lde_bench):
            SEEN.append(lde_bench.channel)
            assert SEEN[0] != SEEN[1]
            assert SEEN[0] not in virtual.channels  # test_a's bench was closed

        def test_c():
            assert SEEN[1] not in virtual.channels
        """
    )
    pytester.runpytest(*PLUGIN).assert_outcomes(passed=3)


def test_a_bus_left_open_is_an_error_at_teardown(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        import can

        LEFT_OPEN = []

        def test_leaks(lde_bench):
            LEFT_OPEN.append(can.Bus(interface="virtual", channel=lde_bench.channel))

        def test_tidy_up():
            LEFT_OPEN.pop().shutdown()
        """
    )
    result = pytester.runpytest(*PLUGIN)
    result.assert_outcomes(passed=2, errors=1)
    result.stdout.fnmatch_lines(["*LeakedBus: 1 bus(es) on the bench's channel*were not shut down*"])


def test_markers_configure_the_fixtures(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        import pytest

        @pytest.mark.lde_bench(profile="hyundai", vehicle="est2", start_ns=2_000_000_000_000_000_000)
        @pytest.mark.lde_sim(scenario="straight", seed=3, duration=1.0, overlay=None)
        @pytest.mark.lde_service(backend="float", drop=["LDE_Overlay"])
        def test_configured(lde_bench, lde_sim, lde_service):
            assert lde_bench.profile.name == "hyundai" and lde_bench.now_ns == 2 * 10**18
            assert lde_sim.sim.scenario.name == "straight" and lde_sim.sim.seed == 3
            assert lde_sim.receiver is None and lde_sim.sim.vehicle.name == "est2"
            assert lde_service.service.backend == "float" and lde_service.bus.drop == {0x3D0}
            lde_bench.run()
            assert len(lde_bench.frames("MDPS12")) > 90 and len(lde_bench.frames("LDE_Overlay")) == 0

        def test_defaults(lde_sim, lde_service):
            assert lde_sim.sim.scenario.name == "heavy_load" and lde_sim.receiver is not None
            assert lde_service.service.backend == "fixed"

        @pytest.mark.lde_sim("straight")
        def test_positional(lde_sim):
            pass
        """
    )
    result = pytester.runpytest(*PLUGIN)
    result.assert_outcomes(passed=2, errors=1)
    result.stdout.fnmatch_lines(["*lde_sim takes keyword arguments only*"])


@pytest.mark.skipif(socketcan_unavailable("vcan0") is None, reason="vcan0 exists here: nothing is skipped")
def test_the_socketcan_option_skips_where_the_kernel_has_no_can(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        def test_on_vcan0(lde_bench):
            raise AssertionError("must not run without SocketCAN")

        def test_without_the_fixtures():
            pass
        """
    )
    result = pytester.runpytest(*PLUGIN, "-rs", "--lde-interface", "socketcan", "--lde-channel", "vcan0")
    result.assert_outcomes(passed=1, skipped=1)
    result.stdout.fnmatch_lines(
        ["*lde bench on socketcan vcan0: no SocketCAN in this kernel*user-mode Linux*"]
    )


def test_bad_options_are_usage_errors(pytester: pytest.Pytester) -> None:
    pytester.makepyfile("def test_x(): pass")
    result = pytester.runpytest(*PLUGIN, "--lde-interface", "pcan")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*--lde-interface: invalid choice: 'pcan'*"])


def test_the_plugin_costs_nothing_to_tests_that_do_not_use_it(pytester: pytest.Pytester) -> None:
    """pytest imports an installed plugin in every project: it must not import lde's bench, the
    service, the simulator or python-can until a test asks for a fixture."""
    pytester.makepyfile(
        """
        import sys

        def test_untouched():
            heavy = [m for m in ("lde.testing.bench", "lde.service.service", "vcan_sim", "numba", "can")
                     if m in sys.modules]
            assert heavy == []
        """
    )
    pytester.runpytest_subprocess(*PLUGIN).assert_outcomes(passed=1)
    fixtures = pytester.runpytest_subprocess(*PLUGIN, "--fixtures").stdout.str()
    for name in ("lde_bench", "lde_bus", "lde_sim", "lde_service"):
        assert f"{name} -- " in fixtures, name
    help_text = pytester.runpytest_subprocess(*PLUGIN, "--help").stdout.str()
    assert "--lde-interface={virtual,socketcan}" in help_text and "--lde-channel" in help_text
