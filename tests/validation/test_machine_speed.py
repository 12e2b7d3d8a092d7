"""validation/machine_speed.py: the speed reference quoted beside wall times runs and prints both figures."""
from __future__ import annotations

import re

from builders import validation_script


def test_machine_speed_prints_a_positive_pass_and_scalar_time(capsys):
    module = validation_script("machine_speed")
    module.main(["--repeats", "1"])
    line = capsys.readouterr().out
    found = re.search(r"pass ([0-9.]+) ms \(([0-9.]+) ns an observation\); scalar ([0-9.]+) us a call", line)
    assert found, line
    pass_ms, per_observation_ns, scalar_us = (float(v) for v in found.groups())
    assert pass_ms > 0 and scalar_us > 0
    # the two pass figures are one measurement in two units (printed to 2 decimals)
    assert abs(per_observation_ns - pass_ms * 1e6 / module.BALL_OBSERVATIONS) < 0.01
