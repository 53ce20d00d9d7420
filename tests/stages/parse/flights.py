"""Small simulated surveys for the parse tests: one straight line, no checkpoints."""

from __future__ import annotations

from pathlib import Path


def simulate_ldmrs_line(output: Path) -> None:
    """A short LD-MRS line in format 3.A (seed 5): 40 m long, 40 m high, at 8 m/s."""
    simulate_line(
        output,
        seed=5,
        formats=["ldmrs_mtig"],
        scanner={"preset": "ldmrs", "angle_step_deg": 4.0},
        altitude_m=40,
        speed_ms=8,
        line_length_m=40,
        lead_in_m=5,
    )


def simulate_line(
    output: Path,
    *,
    seed: int,
    formats: list[str],
    scanner: dict,
    altitude_m: float,
    speed_ms: float,
    line_length_m: float,
    lead_in_m: float,
    navigation: dict | None = None,
) -> None:
    """Simulate one flight line into *output* in the raw *formats* (SPEC 3.A-3.C)."""
    from dtm.commands.simulate.settings import SimulateConfig
    from dtm.commands.simulate.simulator import simulate

    flight = {
        "altitude_m": altitude_m,
        "speed_ms": speed_ms,
        "lines": 1,
        "line_length_m": line_length_m,
        "cross_line": False,
        "lead_in_m": lead_in_m,
    }
    extra = {} if navigation is None else {"navigation": navigation}
    simulate(
        SimulateConfig(
            output=output, seed=seed, formats=formats, checkpoints=0, scanner=scanner, flight=flight, **extra
        )
    )
