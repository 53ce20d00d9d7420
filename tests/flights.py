"""Simulated flights for tests and benchmarks: the simulator's configuration, with what they share spelt once."""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Navigation without errors, for flights whose only errors are the ones a test injects.
PERFECT_NAVIGATION = {"preset": "pos-av-410", "position_noise_m": 0.0, "attitude_noise_deg": 0.0}


def lines(altitude_m: float, speed_ms: float, count: int, length_m: float, **more: Any) -> dict[str, Any]:
    """The ``flight`` block: *count* parallel lines of *length_m*, no cross line, no lead-in unless *more* says."""
    plan = {"altitude_m": altitude_m, "speed_ms": speed_ms, "lines": count, "line_length_m": length_m}
    return {**plan, "cross_line": False, "lead_in_m": 0, **more}


def simulate_flight(output: Path, *, seed: int, formats: list[str], scanner: dict, flight: dict, **more: Any):
    """Simulate a survey into *output*, no check points unless *more* asks (the simulator's result)."""
    from dtm.commands.simulate.settings import SimulateConfig
    from dtm.commands.simulate.simulator import simulate

    config = {"checkpoints": 0, **more}
    return simulate(SimulateConfig(output=output, seed=seed, formats=formats, scanner=scanner, flight=flight, **config))
