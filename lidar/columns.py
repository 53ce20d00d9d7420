"""Columns of numbers between stages: one ``.npy`` file per column, written in chunks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def npy_header(dtype, rows: int, size: int = 128) -> bytes:
    """The fixed-size (*size* bytes) NPY 1.0 header of a 1-D array of *rows* values of *dtype*.

    Written in front of a column whose values were streamed to disk first.
    """
    dtype = np.dtype(dtype)
    header = repr({"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": (int(rows),)})
    body = header.encode("latin1")
    pad = size - 10 - len(body) - 1
    return b"\x93NUMPY\x01\x00" + np.uint16(size - 10).tobytes() + body + b" " * pad + b"\n"


class NpyColumns:
    """Write a table as one ``.npy`` file per column in a folder, streaming.

    Rows are appended in chunks and go straight to disk, so memory does not
    grow with the input; each file's NPY header (fixed 128 bytes) is written
    last, when the row count is known.  ``meta`` goes to ``meta.json``.
    Read back with :func:`read_columns` (memory-mapped).
    """

    HEADER_BYTES = 128

    def __init__(self, folder: Path, schema: dict[str, str], meta: dict | None = None):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.schema = {name: np.dtype(dtype) for name, dtype in schema.items()}
        self.meta = dict(meta or {})
        self.rows = 0
        self._files = {}
        for name in self.schema:
            fh = open(self.folder / f"{name}.npy", "wb")  # noqa: SIM115 - closed in close()
            fh.write(b"\0" * self.HEADER_BYTES)
            self._files[name] = fh

    def append(self, **columns: np.ndarray) -> None:
        lengths = {len(v) for v in columns.values()}
        if set(columns) != set(self.schema) or len(lengths) != 1:
            raise ValueError("append needs every column, all of one length")
        for name, values in columns.items():
            self._files[name].write(np.ascontiguousarray(values, dtype=self.schema[name]).tobytes())
        self.rows += lengths.pop()

    def close(self) -> None:
        for name, fh in self._files.items():
            fh.seek(0)
            fh.write(npy_header(self.schema[name], self.rows))
            fh.close()
        meta = {**self.meta, "rows": self.rows, "columns": {n: str(d) for n, d in self.schema.items()}}
        (self.folder / "meta.json").write_text(json.dumps(meta, indent=2, default=str))

    def __enter__(self) -> NpyColumns:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_columns(folder: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The columns (memory-mapped) and ``meta.json`` of a folder written by :class:`NpyColumns`."""
    folder = Path(folder)
    meta = json.loads((folder / "meta.json").read_text())
    return {name: np.load(folder / f"{name}.npy", mmap_mode="r") for name in meta["columns"]}, meta
