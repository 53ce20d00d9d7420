"""Cloth simulation filter (CSF), through the ``cloth-simulation-filter`` package.

Zhang, W., Qi, J., Wan, P., Wang, H., Xie, D., Wang, X., Yan, G. (2016).  An
easy-to-use airborne LiDAR data filtering method based on cloth simulation.
Remote Sensing 8(6), 501.  doi:10.3390/rs8060501

The package (the authors' C++ code) does the work; this wrapper only maps
parameter names and returns a mask.  The C++ code prints its progress
("[0] Configuring terrain...") on the process's standard output, which is the
user's (``pipeline info --json | jq``, batch logs): :func:`captured_stdout`
takes it at the file-descriptor level and hands it to the debug log.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
import tempfile
from collections.abc import Iterator
from typing import Literal

import CSF
import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from stages.classify_ground.surface import as_xyz

_log = logging.getLogger(__name__)


class CsfParams(StrictModel):
    """The parameters of :func:`csf` (Zhang W. et al. 2016)."""

    name: Literal["csf"] = Field(description="the ground algorithm: csf")
    cloth_resolution: float = Field(0.5, gt=0, description="GR: spacing of the cloth particles, metres")
    rigidness: int = Field(1, ge=1, le=3, description="RI: 1 steep, 2 relief, 3 flat")
    class_threshold: float = Field(0.5, gt=0, description="hcc: distance to the cloth for ground, metres")
    time_step: float = Field(0.65, gt=0, description="dT: simulation time step")
    iterations: int = Field(500, ge=1, description="maximum simulation iterations")
    slope_smooth: bool = Field(True, description="post-process steep slopes")


#: The buffer (m) a CSF tile gets: the cloth is one simulation over the points given, so no buffer makes tiles
#: equal the whole; 50 m is a practical margin, and tiled results may differ within a few metres of tile edges
#: (docs/stages/classify_ground.md, "Tiled and untiled runs").
CLOTH_MARGIN = 50.0


def reach(params: CsfParams) -> float:
    """The buffer a CSF tile gets (:data:`CLOTH_MARGIN`)."""
    return CLOTH_MARGIN


@contextlib.contextmanager
def captured_stdout() -> Iterator[None]:
    """Send what compiled code writes to file descriptor 1 to the debug log instead.

    Python's ``print`` goes through :data:`sys.stdout` and is flushed first;
    C and C++ output (``printf``, ``std::cout``, synchronised with C stdio)
    is flushed with ``fflush(NULL)`` before the descriptor is given back.
    """

    sys.stdout.flush()
    libc = ctypes.CDLL(None)
    saved = os.dup(1)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        try:
            yield
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace").strip()
            if text:
                _log.debug("CSF library output: %s", " | ".join(text.splitlines()))


#: The parameters at their defaults: the function's defaults are the configuration's.
_DEFAULT = CsfParams(name="csf")


def csf(
    xyz: np.ndarray,
    *,
    cloth_resolution: float = _DEFAULT.cloth_resolution,
    rigidness: int = _DEFAULT.rigidness,
    class_threshold: float = _DEFAULT.class_threshold,
    time_step: float = _DEFAULT.time_step,
    iterations: int = _DEFAULT.iterations,
    slope_smooth: bool = _DEFAULT.slope_smooth,
) -> np.ndarray:
    """Classify ground points by dropping a cloth on the inverted cloud: True where a point is ground.

    *xyz*: (n, 3) coordinates (m).  The parameters are the package's, under
    the names of Zhang W. et al. (2016): *cloth_resolution* (m, GR),
    *rigidness* (1 steep, 2 relief, 3 flat; RI), *class_threshold* (m, hcc),
    *time_step* (dT), *iterations*, *slope_smooth* (slope processing).  The
    defaults are the single setting that scored best on the shared ISPRS
    samples (docs/GROUND.md).
    """

    xyz = np.ascontiguousarray(as_xyz(xyz))
    if len(xyz) == 0:
        return np.zeros(0, dtype=bool)
    cloth = CSF.CSF()
    cloth.params.bSloopSmooth = bool(slope_smooth)
    cloth.params.cloth_resolution = float(cloth_resolution)
    cloth.params.rigidness = int(rigidness)
    cloth.params.class_threshold = float(class_threshold)
    cloth.params.time_step = float(time_step)
    cloth.params.interations = int(iterations)  # sic: the package's spelling
    with captured_stdout():
        cloth.setPointCloud(xyz)
    ground, other = CSF.VecInt(), CSF.VecInt()
    with captured_stdout():
        cloth.do_filtering(ground, other, False)
    mask = np.zeros(len(xyz), dtype=bool)
    mask[np.asarray(ground, dtype=np.int64)] = True
    return mask
