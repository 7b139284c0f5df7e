"""The Cortex-M7 estimate: counts checked against the disassembly, output against the host."""

from __future__ import annotations

import pytest

from wftool.analysis.harness import PRESETS

pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")


def test_counts_agree_with_disassembly_and_output_with_the_host(m7, host_harness):
    from wftool.analysis.accfilter import m7_cost, m7_reference_check
    from wftool.analysis.flight import FlightSpec, synthesize

    check = m7_reference_check(m7)
    assert check["executed_instructions"] == check["disassembly_instructions"] > 10
    flight = synthesize(FlightSpec(duration_s=4.0), 800)
    one = m7_cost(m7, host_harness, PRESETS["paper"], flight)
    three = m7_cost(m7, host_harness, PRESETS["harmonics3"], flight)
    assert one.max_deviation < 1e-4 and three.max_deviation < 1e-4
    assert 2.5 < three.process_instructions / one.process_instructions < 3.2
    assert one.cycles_per_sample > one.update_instructions + one.process_instructions  # VDIVs
    assert one.us_per_sample == pytest.approx(one.cycles_per_sample / 216.0)


def test_m7_flags_are_betaflights(filter_tree):
    """The constants in m7.py against the tree's make files (a pin bump that changes them fails)."""
    from wftool.analysis.m7 import M7_ARCH_FLAGS, M7_OPTIMISATION
    from wftool.analysis.sources import make_variables, tree_text

    family = tree_text(filter_tree, "src/platform/STM32/mk/STM32F7.mk")
    assert make_variables(family)["ARCH_FLAGS"] == list(M7_ARCH_FLAGS)
    f722 = family.split("ifeq ($(TARGET_MCU),STM32F722xx)", 1)[-1].split("else")[0]
    assert make_variables(f722).get("OPTIMISE_SPEED") == ["-O2"]
    makefile = make_variables(tree_text(filter_tree, "Makefile"))
    assert makefile["OPTIMISE_DEFAULT"] == ["-O2"]
    base = [f for f in makefile["OPTIMISATION_BASE"] if not f.startswith(("-flto", "-fuse-linker"))]
    assert ["-O2", *base] == list(M7_OPTIMISATION)
    assert "STM32F722xx" in tree_text(filter_tree, "src/platform/STM32/target/STM32F722/target.mk")
