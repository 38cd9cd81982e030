"""``python -m rs_localizer.sim.render``: render timing and a sample frame.

python -m rs_localizer.sim.render --camera vga --frames 10 --save frame.png
"""

import cv2
import numpy as np


def main(argv: list[str] | None = None) -> int:
    """Time the renderer on a preset scene/motion/camera; optionally save the last frame."""
    import argparse
    import time

    from .motion import make_motion, motion_names
    from .renderer import CAMERA_PRESETS, NoiseModel, Renderer, camera_preset, frame_times
    from .scene import load_scene

    p = argparse.ArgumentParser(
        prog="python -m rs_localizer.sim.render", description="Render timing (and a sample frame)"
    )
    p.add_argument("--scene", default="aruco_room")
    p.add_argument("--motion", default="shake", choices=motion_names())
    p.add_argument("--camera", default="vga", choices=sorted(CAMERA_PRESETS))
    p.add_argument("--supersample", type=int, default=2)
    p.add_argument("--exposure", type=float, default=0.0)
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--global-shutter", action="store_true")
    p.add_argument("--save", default=None, help="write the last frame as PNG")
    a = p.parse_args(argv)
    scene = load_scene(a.scene)
    cam = camera_preset(a.camera)
    motion = make_motion(a.motion, scene, duration=a.frames / 30.0)
    r = Renderer(scene, cam, supersample=a.supersample, exposure=a.exposure, noise=NoiseModel())
    shutter = "global" if a.global_shutter else "rolling"
    t = time.perf_counter()
    f = r.render(motion, 0.0, shutter=shutter)
    first = time.perf_counter() - t
    ts = []
    for k in range(a.frames):
        t = time.perf_counter()
        f = r.render(motion, float(frame_times(k)), index=k, shutter=shutter, rng=k)
        ts.append(time.perf_counter() - t)
    print(
        f"{a.scene} {cam.width}x{cam.height} supersample {a.supersample} {shutter}: "
        f"median {np.median(ts) * 1e3:.0f} ms/frame over {a.frames} frames "
        f"(first call {first:.2f} s incl. JIT/cache load)"
    )
    if a.save:
        cv2.imwrite(a.save, f.image[:, :, ::-1])
        print(f"wrote {a.save}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
