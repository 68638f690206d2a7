"""Frame times of `:render` through `nbake serve-inference` (REST): the `Server-Timing: frame;dur` the
server reports and the client's wall time, for `lod` at its finest and coarsest LoD and `lsnif` with
camera rays on the triangles and on the networks. Views are in the artifact's scene and alone under a
grey sky. Path tracing the same scene view at the same size and spp gives the scale.

The artifacts are the integration tests' quick models: the Menger sponge (lod, 20 steps) and the
instanced balls in the Cornell box (lsnif, 60 steps). Their images are not converged; they show what a
frame costs.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.bench.common import BenchSection, median_seconds
from tests.integration.test_inference_server import frame_ms, install_tokens, run_and_publish, start_server
from tests.unit.test_lsnif_model import instanced_scene
from workers.render.render import RenderSettings, render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SIZE, SPP, REPEATS = 64, 4, 3
VIEW = {"camera": {"width": SIZE, "height": SIZE}, "spp": SPP}
VIEWS = {
    "lod": {
        "LoD 0, scene": {"level": 0},
        "coarsest LoD, scene": {"level": 2},
        "LoD 0, neutral": {"level": 0, "background": "neutral"},
    },
    "lsnif": {
        "camera rays on triangles, scene": {},
        "camera rays on lsnif, scene": {"camera_rays": "lsnif"},
        "neutral": {"background": "neutral"},
    },
}


def run() -> list[BenchSection]:
    section = BenchSection(f"inference: :render frame times at {SIZE}x{SIZE}, {SPP} spp (REST)")
    sponge = get_builtin("menger_sponge")
    small = sponge.camera.model_copy(update={"width": 32, "height": 32})  # the tests' evaluation size
    sponge = sponge.model_copy(update={"camera": small})
    scenes = {"lod": sponge, "lsnif": instanced_scene()}
    overrides = {
        "lod": {"samplers": 0, "train": {"steps": 20}},
        "lsnif": {"min_triangles": 1000, "train": {"steps": 60}},
    }
    with tempfile.TemporaryDirectory(prefix="nbake-bench-render-") as folder:
        data_dir, work = Path(folder) / "data", Path(folder) / "work"
        store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
        artifacts = {
            kind: run_and_publish(store, work, kind, scenes[kind], overrides[kind], seed=5) for kind in VIEWS
        }
        install_tokens(data_dir)
        for kind, scene in scenes.items():
            compiled = compile_scene(scene)
            settings = RenderSettings(spp=SPP, width=SIZE, height=SIZE)
            seconds = median_seconds(lambda c=compiled, s=settings: render(c, s), repeats=REPEATS)
            section.add(kind=kind, view="path tracing the scene", frame_ms=1000 * seconds)
        server = start_server(data_dir, [], *artifacts.values())
        try:
            with server.client() as client:
                for kind, views in VIEWS.items():
                    url = f"/v1/artifacts/{artifacts[kind].artifact_id}:render"
                    client.post(url, json={"params": VIEW | {"spp": 1}})  # load the model
                    for name, params in views.items():
                        frames, walls = [], []
                        for _ in range(REPEATS):
                            start = time.perf_counter()
                            response = client.post(url, json={"params": VIEW | params})
                            walls.append(time.perf_counter() - start)
                            response.raise_for_status()
                            frames.append(frame_ms(response))
                        section.add(
                            kind=kind,
                            view=name,
                            frame_ms=statistics.median(frames),
                            client_wall_ms=1000 * statistics.median(walls),
                        )
        finally:
            server.stop()
    section.notes.append(f"medians of {REPEATS}; frame_ms is the server's Server-Timing frame;dur")
    return [section]
