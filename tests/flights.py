"""Simulated flights for tests and benchmarks: the simulator's configuration, with what they share spelt once."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from commands.simulate.settings import SimulateConfig
from commands.simulate.simulator import simulate

#: Cell of the true terrain grid of the tests' flights, metres (none of them reads that grid).
TRUTH_CELL = 4.0

#: Navigation without errors, for flights whose only errors are the ones a test injects.
PERFECT_NAVIGATION = {"preset": "pos-av-410", "position_noise_m": 0.0, "attitude_noise_deg": 0.0}


def lines(altitude_m: float, speed_ms: float, count: int, length_m: float, **more: Any) -> dict[str, Any]:
    """The ``flight`` block: *count* parallel lines of *length_m*, no cross line, no lead-in unless *more* says."""
    plan = {"altitude_m": altitude_m, "speed_ms": speed_ms, "lines": count, "line_length_m": length_m}
    return {**plan, "cross_line": False, "lead_in_m": 0, **more}


def simulate_flight(output: Path, *, seed: int, formats: list[str], scanner: dict, flight: dict, **more: Any):
    """Simulate a survey into *output*, no check points unless *more* asks (the simulator's result).

    The true terrain (``truth/terrain.tif``) on 4-m cells unless *more* asks: these flights' tests read
    the true echoes, not that grid, and at the default 1 m it is a quarter of a small flight's time.
    """
    config = {"checkpoints": 0, "truth_resolution": TRUTH_CELL, **more}
    return simulate(SimulateConfig(output=output, seed=seed, formats=formats, scanner=scanner, flight=flight, **config))


def simulate_ldmrs_line(output: Path) -> None:
    """A short LD-MRS line in format 3.A (seed 5): 40 m long, 40 m high, at 8 m/s, 5 m lead-in."""
    scanner = {"preset": "ldmrs", "angle_step_deg": 4.0}
    simulate_flight(output, seed=5, formats=["ldmrs_mtig"], scanner=scanner, flight=lines(40, 8, 1, 40, lead_in_m=5))
