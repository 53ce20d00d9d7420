"""Where the data beside the repository is: one setting for every test, benchmark and script.

``SHARED_DIR`` names the ``shared`` folder (the ISPRS samples under
``data/isprs``, real surveys under ``data/real``, the seeds); by default it
is ``../shared`` beside the clone.  Set it where the tests run from a copy of
the tree with no ``shared`` beside it (a mutation tool's copy, a container)::

    SHARED_DIR=/work/shared .venv/bin/python -m pytest
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The ``shared`` folder: ``$SHARED_DIR``, else ``../shared`` beside the clone.
SHARED = Path(os.environ.get("SHARED_DIR") or ROOT.parent / "shared").resolve()
#: The data folders under it.
DATA = SHARED / "data"
ISPRS = DATA / "isprs"
REAL = DATA / "real"
