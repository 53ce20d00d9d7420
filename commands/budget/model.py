"""The error budget of seed 2, chapter 4: formulas and the systems table.

Equation numbers are the seed's (``../shared/seeds/001_...``, chapter 4).
Angles are in degrees at the interface, lengths in metres, time in hours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field


def footprint(h: float, divergence_deg: float, aperture_m: float = 0.0) -> float:
    """Laser footprint diameter at nadir, A_L = D + 2 h tan(gamma / 2) (4.6; 4.7 with D = 0).

    >>> round(footprint(300.0, math.degrees(0.003)), 3)  # 4.8: about h * gamma
    0.9
    """
    return aperture_m + 2.0 * h * math.tan(math.radians(divergence_deg) / 2.0)


def footprint_on_slope(h: float, divergence_deg: float, theta_deg: float, slope_deg: float) -> float:
    """Footprint along a slope *i* at scan angle theta (4.9)."""
    g, t, i = math.radians(divergence_deg), math.radians(theta_deg), math.radians(slope_deg)
    num = (math.cos(t + i) + math.sin(t + i) * math.tan(t + i + g / 2.0)) * 2.0 * h * math.sin(g / 2.0)
    return num / math.cos(t - g / 2.0)


def lx_max(h: float, half_scan_deg: float, pointing_error_deg: float, divergence_deg: float) -> float:
    """Across-track footprint with pointing error at the swath edge (4.15, 4.21).

    L_xMAX = h [tan(theta_MAX + e_T + alpha/2) - tan(theta_MAX + e_T - alpha/2)].

    >>> round(lx_max(300.0, 30.0, 1.005, math.degrees(0.003)), 2)  # eq. 4.23
    1.23
    """
    t, e, a = math.radians(half_scan_deg), math.radians(pointing_error_deg), math.radians(divergence_deg)
    return h * (math.tan(t + e + a / 2.0) - math.tan(t + e - a / 2.0))


def ly(h: float, pointing_error_deg: float, divergence_deg: float) -> float:
    """Along-track footprint with pointing error, L_y = h [tan(e_p + a/2) - tan(e_p - a/2)] (4.18)."""
    e, a = math.radians(pointing_error_deg), math.radians(divergence_deg)
    return h * (math.tan(e + a / 2.0) - math.tan(e - a / 2.0))


def ins_error(h: float, attitude_error_deg: float) -> float:
    """Horizontal error from an attitude error, e_SNI = h tan(e_theta) (4.26).

    >>> round(ins_error(300.0, 1.0), 2)  # eq. 4.27
    5.24
    """
    return h * math.tan(math.radians(attitude_error_deg))


def total_error(
    lx: float, e_ins: float, e_gps: float, *, h: float = 0.0, drift_deg_h: float = 0.0, hours: float = 0.0
) -> float:
    """e_T = sqrt(L_x^2 + e_SNI^2 + e_GPS^2) (4.28), plus drift h tan(drift t) in quadrature (SPEC 5).

    >>> round(total_error(1.23, 5.23, 0.45), 2)  # eq. 4.29
    5.39
    """
    drift = ins_error(h, drift_deg_h * hours) if hours else 0.0
    return math.sqrt(lx**2 + e_ins**2 + e_gps**2 + drift**2)


# --------------------------------------------------------------------------
# Catalogue


class _Item(BaseModel):
    model_config = ConfigDict(extra="allow")
    label: str
    cost_usd: float | None = None


class Scanner(_Item):
    max_range_m: float = Field(gt=0)
    range_precision_m: float = Field(gt=0)
    divergence_mrad: float = Field(gt=0)
    half_scan_angle_deg: float = Field(gt=0, lt=90)
    angular_precision_deg: float = Field(ge=0)


class Gps(_Item):
    accuracy_m: float = Field(ge=0)


class Ins(_Item):
    attitude_deg: float = Field(ge=0)
    drift_deg_h: float = Field(ge=0)


class SystemSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scanner: str
    gps: str
    ins: str


class Catalogue(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scanners: dict[str, Scanner]
    gps: dict[str, Gps]
    ins: dict[str, Ins]
    other_costs_usd: dict[str, float] = {}
    systems: dict[str, SystemSpec]

    def merged(self, extra: dict) -> Catalogue:
        """This catalogue with the user's equipment and systems added (or replaced)."""
        data = self.model_dump()
        for key, value in (extra or {}).items():
            if isinstance(value, dict) and isinstance(data.get(key), dict):
                data[key] = {**data[key], **value}
            else:
                data[key] = value
        return Catalogue.model_validate(data)


def load_catalogue(extra: Path | None = None) -> Catalogue:
    """The seed's equipment (``catalogue.yaml`` in this package), plus a user file."""
    text = resources.files("commands.budget").joinpath("catalogue.yaml").read_text(encoding="utf-8")
    catalogue = Catalogue.model_validate(yaml.safe_load(text))
    if extra is not None:
        catalogue = catalogue.merged(yaml.safe_load(Path(extra).read_text(encoding="utf-8")) or {})
    for name, system in catalogue.systems.items():
        for kind in ("scanner", "gps", "ins"):
            table = {"scanner": catalogue.scanners, "gps": catalogue.gps, "ins": catalogue.ins}[kind]
            if getattr(system, kind) not in table:
                raise ValueError(f"system {name}: unknown {kind} '{getattr(system, kind)}'")
    return catalogue


# --------------------------------------------------------------------------
# The table of chapter 4


@dataclass(frozen=True)
class BudgetRow:
    system: str
    laser: str
    gps: str
    ins: str
    in_range: bool
    lx_max_m: float | None
    gps_m: float | None
    ins_drift_deg_h: float | None
    ins_deg: float | None
    total_t0_m: float | None
    total_1h_m: float | None
    total_2h_m: float | None
    cost_usd: float | None
    edge_range_m: float

    COLUMNS = (
        "system",
        "laser",
        "gps",
        "ins",
        "lx_max_m",
        "gps_m",
        "ins_drift_deg_h",
        "ins_deg",
        "total_t0_m",
        "total_1h_m",
        "total_2h_m",
    )


def budget_row(catalogue: Catalogue, system: str, altitude: float, *, range_check: str = "slant") -> BudgetRow:
    """One system's budget at one flying height (a row of Tables 4.1-4.3).

    Parameters
    ----------
    range_check : {"slant", "nadir"}
        ``slant`` (default) refuses heights where the range at the swath edge,
        ``h / cos(theta_MAX)``, exceeds the scanner's maximum range;
        ``nadir`` compares ``h`` itself, which is what the seed's dashes do.
    """
    spec = catalogue.systems[system]
    sc, gp, ins = catalogue.scanners[spec.scanner], catalogue.gps[spec.gps], catalogue.ins[spec.ins]
    edge = altitude / math.cos(math.radians(sc.half_scan_angle_deg))
    reach = edge if range_check == "slant" else altitude
    cost = None
    if all(c is not None for c in (sc.cost_usd, gp.cost_usd, ins.cost_usd)):
        cost = sc.cost_usd + gp.cost_usd + ins.cost_usd + sum(catalogue.other_costs_usd.values())
    common = {
        "system": system,
        "laser": sc.label,
        "gps": gp.label,
        "ins": ins.label,
        "cost_usd": cost,
        "edge_range_m": edge,
    }
    if reach > sc.max_range_m:
        empty = dict.fromkeys(
            ("lx_max_m", "gps_m", "ins_drift_deg_h", "ins_deg", "total_t0_m", "total_1h_m", "total_2h_m")
        )
        return BudgetRow(in_range=False, **common, **empty)
    divergence_deg = math.degrees(sc.divergence_mrad / 1000.0)
    lx = lx_max(altitude, sc.half_scan_angle_deg, sc.angular_precision_deg + ins.attitude_deg, divergence_deg)
    e_ins = ins_error(altitude, ins.attitude_deg)

    def total(hours: float) -> float:
        return total_error(lx, e_ins, gp.accuracy_m, h=altitude, drift_deg_h=ins.drift_deg_h, hours=hours)

    return BudgetRow(
        in_range=True,
        lx_max_m=lx,
        gps_m=gp.accuracy_m,
        ins_drift_deg_h=ins.drift_deg_h,
        ins_deg=ins.attitude_deg,
        total_t0_m=total(0.0),
        total_1h_m=total(1.0),
        total_2h_m=total(2.0),
        **common,
    )


def budget_table(catalogue: Catalogue, altitude: float, *, range_check: str = "slant") -> list[BudgetRow]:
    """Every system of the catalogue at one height, in system order."""
    names = sorted(catalogue.systems, key=lambda s: (len(s), s))
    return [budget_row(catalogue, name, altitude, range_check=range_check) for name in names]
