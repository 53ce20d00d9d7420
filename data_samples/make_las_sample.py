"""Regenerate data_samples/las/sample.laz and its truth (deterministic: the same points, byte for byte).

    python data_samples/make_las_sample.py [FOLDER]

Writes sample.laz, checkpoints.csv (60 check points on the true terrain, a
third under trees) and truth_terrain.tif (the true terrain at 1 m) into
FOLDER (default: data_samples/las).

Provenance: synthetic, made by tests.synthetic.make_scene with its default
arguments (512 m x 384 m, 1.5 pulses/m2, 3 cm vertical noise, seed 20111),
written in ETRS89 / UTM 30N (EPSG:25830) with origin E 440000, N 4474000.
"""

import sys
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the shipped sample.laz's header: the day it was made, and the generator's name then (it lived in
#: stages.synthetic before it moved to tests.synthetic), so that the file is made again byte for byte
CREATED = date(2026, 11, 22)
SOFTWARE = "stages.synthetic.make_scene"


def main(folder: Path) -> None:
    """Write the sample, its check points and its true terrain into *folder*."""
    sys.path.insert(0, str(ROOT))  # tests.synthetic lives in the repository, whatever the working folder
    from tests.synthetic import SAMPLE_ORIGIN, make_scene, sample_checkpoints, write_scene_las, write_truth_raster

    folder.mkdir(parents=True, exist_ok=True)
    scene = make_scene()
    write_scene_las(scene, folder / "sample.laz", created=CREATED, software=SOFTWARE)
    print(f"{folder / 'sample.laz'}: {len(scene.x)} points, {int(scene.true_ground.sum())} on the ground")
    x, y, z, cover = sample_checkpoints()
    with open(folder / "checkpoints.csv", "w", encoding="utf-8") as fh:
        fh.write("# true terrain of the synthetic sample; EPSG:25830, ellipsoidal heights, metres\n")
        fh.write("id,x,y,z,land_cover\n")
        for i, row in enumerate(zip(x, y, z, cover, strict=True), 1):
            fh.write(
                f"CP{i:03d},{row[0] + SAMPLE_ORIGIN[0]:.3f},{row[1] + SAMPLE_ORIGIN[1]:.3f},{row[2]:.3f},{row[3]}\n"
            )
    print(f"{folder / 'checkpoints.csv'}: {len(x)} check points")
    write_truth_raster(folder / "truth_terrain.tif")
    print(f"{folder / 'truth_terrain.tif'}: true terrain at 1 m")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "las")
