"""A Mitsuba 3 scene from the plain (JSON) dictionary `mitsuba_scene.mitsuba_scene_file` writes, and, run as
a script, a render of one: `python tests/support/mitsuba_load.py scene.json out.exr SPP SEED THREADS`.

This module imports nothing but Mitsuba (Dr.Jit with it) and the standard library, so a fresh process
running it pays Mitsuba's own start-up, scene load and render, and nothing of ours: the cold side of
`tests/bench/bench_render.py`'s comparison.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

MATRIX = "matrix4x4"  # the key a plain dictionary stores a 4x4 transform under


def loadable(node):
    """`node` with every {MATRIX: rows} made a `mitsuba.ScalarTransform4f` (the variant must be set)."""
    import mitsuba as mi

    if isinstance(node, dict):
        if set(node) == {MATRIX}:
            return mi.ScalarTransform4f(node[MATRIX])
        return {key: loadable(value) for key, value in node.items()}
    return node


def load_scene(path: Path, threads: int):
    """The scene of a plain dictionary file, in `scalar_rgb` on `threads` threads."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    dr.set_thread_count(threads)
    return mi.load_dict(loadable(json.loads(Path(path).read_text())))


def main(argv: list[str]) -> None:
    import mitsuba as mi

    scene_file, output, spp, seed, threads = argv
    scene = load_scene(Path(scene_file), int(threads))
    image = mi.render(scene, spp=int(spp), seed=int(seed))
    mi.Bitmap(image).write(output)


if __name__ == "__main__":
    main(sys.argv[1:])
