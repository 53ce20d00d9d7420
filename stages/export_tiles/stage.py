"""Stage ``export_tiles``: large elevation rasters as square GeoTIFF tiles plus a GDAL VRT mosaic.

Runs when ``stages.export_tiles.tile_size`` is set: each raster of
``rasters`` (default ``[dtm]``) becomes ``tiles/<raster>/<raster>_<E>_<N>.tif``
(COGs on a grid of whole tile sides, named by their lower-left corner) and
``<raster>.vrt``, which reads as the untiled raster, cell for cell
(:mod:`stages.export_tiles.cog_tiles`; docs/stages/export_tiles.md).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from pipeline.stage import Stage, StageContext, StageIO, StageParams
from stages.export_tiles.cog_tiles import tile_cells, tile_count, write_tiles


class ExportTilesParams(StageParams):
    tile_size: float | None = Field(
        None,
        ge=1.0,
        description="side of the tiles, metres, a whole number of raster cells (e.g. 1000); none (default) = no "
        "tiles: the rasters stay single files",
    )
    rasters: list[Literal["dtm", "dsm", "ndsm"]] = Field(
        ["dtm"], min_length=1, description="rasters written as tiles, each with its VRT: dtm, dsm, ndsm"
    )


class ExportTiles(Stage, name="export_tiles", version="2", params=ExportTilesParams):
    """DTM (and DSM, nDSM) as GeoTIFF tiles plus a VRT mosaic, when tile_size is set."""

    inputs = ("dtm",)
    outputs: ClassVar = {"tiles": "tiles", "dtm_vrt": "dtm.vrt"}
    products: ClassVar = {"tiles": "tiles", "dtm_vrt": "dtm.vrt"}
    config_keys = ("stages.rasterize.resolution",)

    def is_enabled(self, params, config) -> bool:
        return bool(params.enabled) and params.tile_size is not None

    def declare(self, params, config) -> StageIO:
        if params.tile_size is not None:
            tile_cells(params.tile_size, config.stages.rasterize.resolution)  # a ConfigError before anything runs
        rasters = list(dict.fromkeys(params.rasters))
        outputs = {"tiles": "tiles", **{f"{r}_vrt": f"{r}.vrt" for r in rasters}}
        return StageIO(tuple(rasters), outputs, dict(outputs))

    def run(self, ctx: StageContext[ExportTilesParams]) -> None:
        p = ctx.params
        cells = tile_cells(p.tile_size, ctx.setting("stages.rasterize.resolution"))
        root = ctx.outputs["tiles"]
        root.mkdir(parents=True, exist_ok=True)
        counts = {}
        rasters = list(dict.fromkeys(p.rasters))
        with ctx.progress(sum(tile_count(ctx.inputs[r], cells) for r in rasters), "tiles cut", unit="tiles") as bar:
            for raster in rasters:
                tiles = write_tiles(
                    ctx.inputs[raster],
                    root / raster,
                    ctx.outputs[f"{raster}_vrt"],
                    raster,
                    cells,
                    f"tiles/{raster}",
                    advance=bar.update,
                )
                counts[raster] = len(tiles)
                ctx.log.info("%s: %d tiles of %d x %d cells, %s.vrt", raster, len(tiles), cells, cells, raster)
        ctx.metrics.update(tile_cells=cells, tiles=counts)
