"""``pipeline budget``: seed 2's error budget for every system at a flying height.

    pipeline budget --altitude 600 [--format csv|md] [--catalogue MY.yaml]
                    [--range-check slant|nadir] [--plots DIR]

Columns: ``system,laser,gps,ins,lx_max_m,gps_m,ins_drift_deg_h,ins_deg,
total_t0_m,total_1h_m,total_2h_m``; a system whose scanner cannot reach the
ground at that height has empty cells (CSV) or dashes (Markdown), as the
seed's tables do.  ``--catalogue`` adds the user's equipment and systems
(same layout as ``commands/budget/catalogue.yaml``).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from pipeline.errors import ConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--altitude", type=float, required=True, metavar="H", help="flying height above ground, metres")
    p.add_argument("--format", choices=["csv", "md"], default="csv", help="table format (default csv)")
    p.add_argument("--catalogue", type=Path, help="YAML with more equipment and systems")
    p.add_argument(
        "--range-check",
        choices=["slant", "nadir"],
        default="slant",
        help="refuse heights where the range at the swath edge (slant, default) or at nadir (the seed's rule) exceeds the scanner's",
    )
    p.add_argument(
        "--plots", type=Path, metavar="DIR", help="also write Figures 4.11-4.14 and the cost-precision chart (PNG)"
    )


def _cell(value, md: bool) -> str:
    if value is None:
        return "—" if md else ""
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def run(args: argparse.Namespace) -> int:
    # lazy: pydantic and YAML, loaded when the command runs, not by pipeline --help (start-up time)
    from commands.budget.model import BudgetRow, budget_table, load_catalogue

    if args.altitude <= 0:
        raise ConfigError(f"--altitude {args.altitude:g}: the flying height must be positive.")
    if args.catalogue is not None and not args.catalogue.is_file():
        raise ConfigError(f"--catalogue {args.catalogue}: file not found.")
    try:
        catalogue = load_catalogue(args.catalogue)
    except Exception as exc:  # pydantic or YAML errors in the user's catalogue
        raise ConfigError(f"--catalogue {args.catalogue}: {str(exc).splitlines()[0]}.") from None
    rows = budget_table(catalogue, args.altitude, range_check=args.range_check)
    if args.format == "csv":
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(BudgetRow.COLUMNS)
        for row in rows:
            writer.writerow([_cell(getattr(row, c), False) for c in BudgetRow.COLUMNS])
    else:
        print("| " + " | ".join(BudgetRow.COLUMNS) + " |")
        print("|" + "---|" * len(BudgetRow.COLUMNS))
        for row in rows:
            print("| " + " | ".join(_cell(getattr(row, c), True) for c in BudgetRow.COLUMNS) + " |")
    if args.plots:
        from commands.budget.plots import write_plots  # lazy: Matplotlib, not for pipeline --help (start-up time)

        for path in write_plots(catalogue, args.plots):
            print(f"wrote {path}", file=sys.stderr)
    return 0
