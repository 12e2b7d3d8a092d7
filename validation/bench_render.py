"""Render time of paper_sphere, one image per light at 1 spp, LLVM variant beside the scalar one.

Both variants render the same scene with Mitsuba's own film loop (``mi.render``) and the
rjfit plugin; the scalar variant calls the Python plugin once per sample, which is why it
is slow. The LLVM figure is given with and without the first light (kernel compilation).

    .venv/bin/python validation/bench_render.py [--resolution 256] [--variants llvm_ad_rgb scalar_rgb]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from rjfit.data.lights import Light
from rjfit.render.mitsuba_scene import activate, build_scene
from rjfit.render.render import load_scene_definition, write_mesh_parts


def time_variant(variant: str, definition: dict, mesh_dir: Path, meshes) -> dict:
    mi = activate(variant)
    parts = [(mesh_dir.parent / entry["file"], entry["material"]) for entry in meshes]
    lights = [Light.from_json(entry) for entry in definition["lights"]]
    seconds = []
    for index, light in enumerate(lights):
        started = time.perf_counter()
        scene = build_scene(definition["camera"], definition["resolution"], parts, definition["materials"], [light],
                            reference_intensity=definition["reference_intensity"], max_depth=8)
        image = mi.render(scene, spp=1, seed=index)
        _ = float(image.numpy().sum()) if hasattr(image, "numpy") else None
        seconds.append(time.perf_counter() - started)
    return {"variant": variant, "total": sum(seconds), "first": seconds[0],
            "rest_mean": sum(seconds[1:]) / max(len(seconds) - 1, 1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--variants", nargs="+", default=["llvm_ad_rgb", "scalar_rgb"])
    args = parser.parse_args()
    definition = load_scene_definition("paper_sphere")
    definition["resolution"] = [args.resolution, args.resolution]
    with tempfile.TemporaryDirectory() as folder:
        mesh_dir = Path(folder) / "meshes"
        meshes = write_mesh_parts(definition["geometry"], mesh_dir)
        rows = [time_variant(variant, definition, mesh_dir, meshes) for variant in args.variants]
    print(f"paper_sphere {args.resolution} x {args.resolution}, {len(definition['lights'])} lights, 1 spp, path (max_depth 8)")
    print(f"{'variant':<14} {'total s':>9} {'first light s':>14} {'per later light s':>18}")
    for row in rows:
        print(f"{row['variant']:<14} {row['total']:>9.2f} {row['first']:>14.2f} {row['rest_mean']:>18.3f}")
    if len(rows) > 1:
        print(f"ratio {rows[1]['variant']} / {rows[0]['variant']} (total): {rows[1]['total'] / rows[0]['total']:.1f}x")


if __name__ == "__main__":
    main()
