"""validation/machine_speed.py: the speed reference quoted beside wall times runs and prints both figures."""
from __future__ import annotations

import importlib.util
import re

from builders import REPO_ROOT


def test_machine_speed_prints_a_positive_pass_and_scalar_time(capsys):
    spec = importlib.util.spec_from_file_location("machine_speed", REPO_ROOT / "validation" / "machine_speed.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(["--repeats", "1"])
    line = capsys.readouterr().out
    found = re.search(r"pass ([0-9.]+) ms \(([0-9.]+) ns an observation\); scalar ([0-9.]+) us a call", line)
    assert found, line
    pass_ms, per_observation_ns, scalar_us = (float(v) for v in found.groups())
    assert pass_ms > 0 and scalar_us > 0
    # the two pass figures are one measurement in two units (printed to 2 decimals)
    assert abs(per_observation_ns - pass_ms * 1e6 / module.BALL_OBSERVATIONS) < 0.01
