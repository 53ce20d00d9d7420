"""Regenerate data_samples/las/sample.laz (deterministic: same seed, same file content).

    python data_samples/make_las_sample.py

Provenance: synthetic, made by stages.synthetic.make_scene with its default
arguments (512 m x 384 m, 1.5 pulses/m2, 3 cm vertical noise, seed 20111),
written in ETRS89 / UTM 30N (EPSG:25830) with origin E 440000, N 4474000.
"""

from pathlib import Path

from stages.synthetic import make_scene, write_scene_las

if __name__ == "__main__":
    out = Path(__file__).resolve().parent / "las" / "sample.laz"
    out.parent.mkdir(parents=True, exist_ok=True)
    scene = make_scene()
    write_scene_las(scene, out)
    print(f"{out}: {len(scene.x)} points, {int(scene.true_ground.sum())} on the ground")
