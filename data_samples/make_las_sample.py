"""Regenerate data_samples/las/sample.laz (deterministic: same seed, same file content).

    python data_samples/make_las_sample.py

Also writes checkpoints.csv (60 check points on the true terrain, a third
under trees) and truth_terrain.tif (the true terrain at 1 m).

Provenance: synthetic, made by tests.synthetic.make_scene with its default
arguments (512 m x 384 m, 1.5 pulses/m2, 3 cm vertical noise, seed 20111),
written in ETRS89 / UTM 30N (EPSG:25830) with origin E 440000, N 4474000.
"""

from pathlib import Path

from tests.synthetic import SAMPLE_ORIGIN, make_scene, sample_checkpoints, write_scene_las, write_truth_raster

if __name__ == "__main__":
    folder = Path(__file__).resolve().parent / "las"
    folder.mkdir(parents=True, exist_ok=True)
    scene = make_scene()
    write_scene_las(scene, folder / "sample.laz")
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
