"""The scenarios' list: each once, each of a set-up, those that arm last and saying why they
need `--arm`. (Each scenario is played on the patched SITL by tests/sitl/test_uplink_safety.py.)"""

from __future__ import annotations

from wftool.preflight.scenarios import ALONE, BY_KEY, PILOT, SCENARIOS, scenarios_for


def test_each_scenario_once_of_a_set_up() -> None:
    keys = [scenario.key for scenario in SCENARIOS]
    assert len(keys) == len(set(keys)) == len(BY_KEY)
    titles = [scenario.title for scenario in SCENARIOS]
    assert len(titles) == len(set(titles))
    assert all(set(scenario.setups) <= {PILOT, ALONE} and scenario.setups for scenario in SCENARIOS)


def test_the_issues_scenarios_are_there() -> None:
    pilot = {s.key for s in scenarios_for(alone=False)}
    alone = {s.key for s in scenarios_for(alone=True)}
    common = {"stopped", "closed", "stuck", "garbage", "replay", "twin", "clock_step",
              "out_of_range", "late"}  # fmt: skip
    assert common <= pilot and common <= alone
    assert {"switch_early", "resume", "reengage", "restart", "switch_off", "radio_lost"} <= pilot
    assert {"restart_armed", "default_command", "stage2"} <= alone


def test_those_that_need_arm_say_why_and_come_last() -> None:
    for setup in (False, True):
        played = scenarios_for(alone=setup)
        arming = [i for i, scenario in enumerate(played) if scenario.needs_arm]
        assert arming == list(range(len(played) - len(arming), len(played)))
    assert BY_KEY["stage2"].needs_arm == "Betaflight enters stage 2 only armed"
