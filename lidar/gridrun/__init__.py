"""The run service of the grid stages: a stage says what it computes on a window of the survey's grid, this decides where.

:mod:`lidar.gridrun.kernel` is the contract (:class:`~lidar.gridrun.kernel.GridKernel`),
:mod:`lidar.gridrun.service` the one entry (:func:`~lidar.gridrun.service.run_grid_stage`);
:mod:`~lidar.gridrun.passes`, :mod:`~lidar.gridrun.windows` and :mod:`~lidar.gridrun.point_tiles`
are its three ways of running: passes over the records, the grid in the tiles' windows, tiles of points.
"""
