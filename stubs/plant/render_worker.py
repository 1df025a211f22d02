"""The cell's cameras rendered in a process of their own (``python -m stubs.child
stubs.plant.render_worker NAME:WxH ...``), so that rendering never holds warden's GIL.

MuJoCo's renderer holds the GIL while it draws (here, with software EGL, about 20 ms for a 224 ×
224 frame with shadows and reflections, which are therefore off, about 1 ms without): on a
thread of warden's process it stalled the 2 ms control loop by up to 8 ms. So the renderer is a
child, like a camera is a device of its own. The exchange is fixed size on stdin/stdout, so it
needs no framing: the child first writes the model's ``nq`` (4 bytes, little-endian); then, for
every ``nq`` float64 joint positions it reads, it writes each camera's RGB pixels (``H × W × 3``
bytes, in the order named). It exits at the end of its input. It needs ``MUJOCO_GL=egl``, which
the parent sets in its environment.
"""

from __future__ import annotations

import dataclasses
import struct
import sys

import mujoco
import numpy as np

from stubs.plant.cameras import SIM_SPECS, CameraSpec, render_model


def _specs(argv: list[str]) -> tuple[CameraSpec, ...]:
    """``NAME:WxH`` for each camera (the parent writes them: not checked again here)."""
    specs = []
    for text in argv:
        name, _, size = text.partition(":")
        width, _, height = size.partition("x")
        specs.append(dataclasses.replace(SIM_SPECS[name], width=int(width), height=int(height)))
    return tuple(specs)


def main(argv: list[str]) -> int:
    specs = _specs(argv)
    model = render_model(specs)
    data = mujoco.MjData(model)
    renderers = [(s.name, mujoco.Renderer(model, s.height, s.width)) for s in specs]
    for _, renderer in renderers:  # software EGL: a 4096² shadow map made a frame 20× dearer
        for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION):
            renderer.scene.flags[flag] = False
    source, sink = sys.stdin.buffer, sys.stdout.buffer
    sink.write(struct.pack("<I", model.nq))
    sink.flush()
    size = model.nq * 8
    while len(request := source.read(size)) == size:
        data.qpos[:] = np.frombuffer(request, dtype="<f8")
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        for name, renderer in renderers:
            renderer.update_scene(data, camera=name)
            sink.write(renderer.render().tobytes())
        sink.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
