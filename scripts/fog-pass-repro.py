"""Render chosen passes of one height-fog terrain scene (scenes/library/fog_terrain_e<E>_<TRANSPORT>.toml,
E the ELEVATION: 5, 10, 15, 30, 40 or 60) as `rtfit run height-fog` renders it (issue 21 §1 repro).

    python3 scripts/fog-pass-repro.py VARIANT ELEVATION TRANSPORT PASSES [WIDTH HEIGHT SPP]
    python3 scripts/fog-pass-repro.py cuda_ad_rgb 5 single 0,1,2,3,4,5,6,7

Each pass is seeded as the experiment seeds it (run seed 0, ``sub_seed(0, "pass", i)``) at the full
configuration (256×128, 256 spp per pass) and prints its time and samples/s; a pass that breaks its
medium-event cap prints the one-line budget error. Run it under ``timeout``: before the fix of issue 21
pass 1 of ``5 single`` never returned on an H200.
"""

import dataclasses
import sys
import time

from rtfit.reference.budget import PassBudgetExceeded
from rtfit.reference.build import load_mitsuba_scene
from rtfit.reference.estimators import radiance_pass, sub_seed
from rtfit.scenes import library_path, load_scene


def main(argv):
    variant, elevation, transport, passes = argv[1], float(argv[2]), argv[3], argv[4]
    width, height, spp = (int(x) for x in (argv[5:8] if len(argv) > 7 else (256, 128, 256)))
    scene = load_scene(library_path(f"fog_terrain_e{elevation:g}_{transport}"))
    scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, width=width, height=height))
    mi, ms = load_mitsuba_scene(scene, variant)
    for i in (int(x) for x in passes.split(",")):
        t0 = time.perf_counter()
        try:
            r = radiance_pass(mi, ms, spp, sub_seed(0, "pass", i))
        except PassBudgetExceeded as e:
            print(f"pass {i}: {e}", flush=True)
            continue
        t = time.perf_counter() - t0
        rate = width * height * spp / t / 1e6
        print(f"pass {i}: {t:.3f} s, {rate:.1f} Msamples/s, mean RGB {r.mean.mean(axis=(0, 1))}", flush=True)


if __name__ == "__main__":
    main(sys.argv)
