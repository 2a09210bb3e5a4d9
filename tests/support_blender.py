"""Import BVH files into Blender headless and read back every bone's world position per frame.

Two halves in one file:

- :func:`blender_bvh_positions` (pytest side) runs ``blender -b --factory-startup --python
  <this file> -- OUT.json FILE.bvh...``, one Blender launch for any number of files;
- :func:`_main` (Blender side, run by that command) imports each file with Blender's own BVH
  importer (``bpy.ops.import_anim.bvh``, default options: Y up in the file, -Z forward), steps
  through the imported frames, and writes, per file, the bone count, the frame range and every
  bone head's world position (Blender's frame, metres = file units / 100: our BVH is in cm).

Debian's Blender 3.4 importer opens the file with mode ``'rU'``, which its Python 3.11 refuses
(``ValueError: invalid mode: 'rU'``): the Blender side maps that mode to ``'r'`` around the
import (the same text mode; universal newlines are the default since Python 3).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

BLENDER_TIMEOUT_S = 300.0


def blender_executable() -> str | None:
    """Debian's ``blender`` (``/usr/bin/blender`` or on PATH), else None."""
    if Path("/usr/bin/blender").is_file():
        return "/usr/bin/blender"
    return shutil.which("blender")


def blender_bvh_positions(blender: str, files: list[Path], out: Path) -> list[dict[str, Any]]:
    """Import ``files`` into one Blender session; per file, what :func:`_main` wrote.

    Each result: ``bones`` (names, file order as Blender lists them), ``frame_start``,
    ``frame_end`` (the action's keyed range), ``positions`` ((frames, bones, 3) world
    positions of the bone heads, metres, in the BVH's own axes: Y up).

    Raises:
        RuntimeError: Blender failed or wrote nothing (its output is in the message).
    """
    import numpy as np  # here, not at the top: Blender's own Python runs this file without numpy

    command = [blender, "-b", "--factory-startup", "--python-exit-code", "3", "--python", __file__]
    command += ["--", str(out)]
    command += [str(f) for f in files]
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run(
        command, capture_output=True, text=True, timeout=BLENDER_TIMEOUT_S, env=env, check=False
    )
    if done.returncode != 0 or not out.is_file():
        raise RuntimeError(
            f"blender exited {done.returncode}\nstdout:\n{done.stdout[-4000:]}\n"
            f"stderr:\n{done.stderr[-4000:]}"
        )
    results: list[dict[str, Any]] = json.loads(out.read_text(encoding="utf-8"))
    for result in results:
        blender_xyz = np.asarray(result["positions"], dtype=np.float64)
        # The importer turned the file's Y-up, -Z-forward axes into Blender's Z up, -Y forward:
        # Blender (x, y, z) = file (x, -z, y). Back to the file's axes, and cm to metres.
        result["positions"] = (
            np.stack([blender_xyz[..., 0], blender_xyz[..., 2], -blender_xyz[..., 1]], axis=-1)
            / 100.0
        )
    return results


# --- Blender side --------------------------------------------------------------------------------


def _import_bvh(bpy: Any, path: str) -> Any:
    """Import one BVH with the importer's defaults; returns the new armature object."""
    import builtins

    real_open = builtins.open

    def open_without_u(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        return real_open(file, mode.replace("U", "") or "r", *args, **kwargs)

    before = set(bpy.data.objects)
    builtins.open = open_without_u
    try:
        bpy.ops.import_anim.bvh(filepath=path)
    finally:
        builtins.open = real_open
    (armature,) = [o for o in bpy.data.objects if o not in before and o.type == "ARMATURE"]
    return armature


def _main(argv: list[str]) -> None:
    import bpy

    out, *files = argv
    scene = bpy.context.scene
    results = []
    for path in files:
        armature = _import_bvh(bpy, path)
        action = armature.animation_data.action
        start, end = (round(f) for f in action.frame_range)
        bones = list(armature.pose.bones)
        positions = []
        for frame in range(start, end + 1):
            scene.frame_set(frame)
            world = armature.matrix_world
            positions.append([list(world @ bone.head) for bone in bones])
        results.append({
            "file": path,
            "bones": [bone.name for bone in bones],
            "frame_start": start,
            "frame_end": end,
            "positions": positions,
        })  # fmt: skip
        armature.hide_set(True)
    Path(out).write_text(json.dumps(results), encoding="utf-8")


if __name__ == "__main__" and "bpy" in sys.modules:
    _main(sys.argv[sys.argv.index("--") + 1 :])
