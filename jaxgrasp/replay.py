"""``python -m jaxgrasp.replay OBJECT --grasp x,y,z,qw,qx,qy,qz --out trial.gif``.

Renders one grasp trial (MuJoCo C, the same rollout the learner scores) with MuJoCo's
offscreen renderer: the gripper stays where the grasp puts it, the object is placed, the
fingers close and the object's weight pulls (world = grasp frame, so the weight's direction
is the object's own -z). The outcome is written on every frame. On a machine without a
display, MuJoCo renders through EGL (``MUJOCO_GL=egl``, Mesa's ``libegl1`` on a CPU) by
default; set ``MUJOCO_GL=osmesa`` for OSMesa.
"""

import argparse
import io
import os
import sys
from pathlib import Path

# the GL backend is chosen when mujoco is first imported: headless EGL unless told otherwise
os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image, ImageDraw  # noqa: E402

from jaxgrasp import objects
from jaxgrasp._cli import USER_ERRORS, fail  # noqa: E402
from jaxgrasp.learn.files.atomic import atomic_write_bytes  # noqa: E402
from jaxgrasp.physics import (  # noqa: E402
    GRIPPERS,
    Outcome,
    check_grasps,
    gripper,
    load_scene,
    rules,
)
from jaxgrasp.physics.mujoco_backend import MujocoEngine  # noqa: E402

__all__ = ["render_trial", "main"]


def _camera_model(scene, target, distance, azimuth, elevation):
    """The scene with a camera on the object body, looking at ``target`` (object frame) with
    the object's +z up: the object stays upright on screen and the gripper moves over it."""
    az, el = np.radians(azimuth), np.radians(elevation)
    eye = np.asarray(target) - distance * np.array(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    spec = mujoco.MjSpec.from_string(scene.xml)
    spec.body("object").add_camera(name="replay", pos=eye,
                                   xyaxes=[*right, *np.cross(right, forward)])
    m = spec.compile()
    m.vis.headlight.ambient[:] = 0.45
    m.vis.headlight.diffuse[:] = 0.6
    return m


def render_trial(obj, grasp, *, gripper=None, every: int = 2, size=(480, 360),
                 distance: float = 0.5, azimuth: float = -60.0, elevation: float = -25.0):
    """``(frames, outcome name)``: RGB frames (H, W, 3) of the trial of ``grasp`` (7,) with
    ``gripper`` (GripperParams, default: the default gripper)."""
    grasp = check_grasps(np.asarray(grasp, np.float32).reshape(1, 7), "grasp", finite=True)
    scene = load_scene(obj, gripper=gripper)
    engine = MujocoEngine(scene, nthread=1)
    raw = engine(grasp)  # the trial's decisions (epsilon is not needed for the outcome)
    outcome = Outcome(int(rules.decide_outcome(raw["collision"], raw["miss"], raw["slipped"],
                                               raw["bad"], xp=np)[0])).name
    qpos, collision = engine.place(grasp)
    states = (qpos[:, None] if collision[0]
              else engine.rollout(qpos)[:, ::every, 1:1 + engine.nq])[0]
    m = _camera_model(scene, np.asarray(grasp[0, :3], np.float64), distance, azimuth,
                      elevation)
    d = mujoco.MjData(m)
    frames = []
    with mujoco.Renderer(m, height=size[1], width=size[0]) as renderer:
        for k, q in enumerate(states):
            d.qpos[:] = q
            mujoco.mj_forward(m, d)
            renderer.update_scene(d, camera="replay")
            img = Image.fromarray(renderer.render())
            ImageDraw.Draw(img).text(
                (8, 8), f"{scene.obj.name}  step {k * every}/{scene.params.num_steps}  "
                f"-> {outcome}", fill=(255, 255, 255))
            frames.append(np.asarray(img))
    return frames, outcome


def save_frames(frames, path, fps: int = 20) -> Path:
    """Write frames as an animated GIF (atomically)."""
    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"{path}: only .gif is written (MP4 would need ffmpeg, which "
                         "jaxgrasp does not install); use a .gif name")
    images = [Image.fromarray(f) for f in frames]
    buf = io.BytesIO()
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:],
                   duration=int(1000 / fps), loop=0)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _grasp(text: str) -> np.ndarray:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--grasp must be 7 comma-separated numbers, got {text!r}") from None
    if len(values) != 7:
        raise ValueError(f"--grasp must be 7 numbers x,y,z,qw,qx,qy,qz, got {len(values)}")
    return np.asarray(values, np.float32)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m jaxgrasp.replay", description=__doc__.splitlines()[0],
        epilog="example: python -m jaxgrasp.replay pitcher "
               "--grasp 0.0,0.12,0.1,0.707,0.707,0,0 --out trial.gif")
    p.add_argument("object", help="a shipped object name or a mesh file (.obj/.stl/.ply)")
    p.add_argument("--grasp", required=True, help="x,y,z,qw,qx,qy,qz in the object frame")
    p.add_argument("--out", required=True, help="the animated GIF to write")
    p.add_argument("--gripper", choices=list(GRIPPERS), default="default")
    p.add_argument("--every", type=int, default=2, help="draw every N-th physics step")
    p.add_argument("--fps", type=int, default=20)
    args = p.parse_args(argv)
    try:
        if args.every < 1 or args.fps < 1:
            raise ValueError("--every and --fps must be positive")
        frames, outcome = render_trial(objects.load_any(args.object), _grasp(args.grasp),
                                       gripper=gripper(args.gripper), every=args.every)
        out = save_frames(frames, args.out, fps=args.fps)
    except USER_ERRORS as err:
        return fail(err)
    print(f"{outcome}: wrote {out} ({len(frames)} frames)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
