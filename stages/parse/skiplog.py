"""What the text readers share: counters that keep the first places something was skipped, and opening (gzip too)."""

from __future__ import annotations

import gzip
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

MAX_LOCATIONS = 20


@dataclass
class SkipLog:
    """Base of a reader's counters: the first places where something was skipped."""

    locations: list[str] = field(default_factory=list)  # "file, line N: what"

    def note(self, where: str) -> None:
        if len(self.locations) < MAX_LOCATIONS:
            self.locations.append(where)


def open_text(path: str | Path, encoding: str = "utf-8") -> TextIO:
    """Open a text input for reading; ``.gz`` files are decompressed on the fly (streamed)."""
    if Path(path).suffix == ".gz":
        return gzip.open(path, "rt", encoding=encoding, errors="replace")
    return open(path, encoding=encoding, errors="replace")
