"""The price of a traced ray in network FLOPs on this machine, against the fixed one `prt` chooses its frame's
spp with (`PrtConfig.flops_per_ray`, `workers.models.prt.frame_spp`).

Per scene, on the report's view of the default preset: seconds a ray of 16-spp path tracing (one thread)
over seconds a FLOP of a fresh default network's frame (one torch thread), medians of `REPEATS`. A machine
far from the config's price would choose differently if it timed; the job never does, so this only says
how well the fixed price fits the machine measured.
"""

from __future__ import annotations

import statistics

import numpy as np
import torch

from tests.bench.common import BenchSection
from workers.models.prt.evaluate import report_view
from workers.models.prt.frame import render_frame
from workers.models.prt.network import PrtNetwork
from workers.models.registry import get_kind
from workers.render.render import render
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

SCENES = ("env_lit_objects", "glossy_row")
REPEATS = 5
SPP = 16


def run() -> list[BenchSection]:
    config = get_kind("prt").resolve_config("default", {})
    section = BenchSection(f"prt: network FLOPs a traced ray costs here (config: {config.flops_per_ray:g})")
    torch.set_num_threads(1)
    for name in SCENES:
        scene = SceneRef(get_builtin(name))
        torch.manual_seed(0)
        model = PrtNetwork(config).eval()
        view = report_view(scene, config, 0)
        box = np.array([[-4.0] * 3, [4.0] * 3])
        objects = np.arange(len(scene.spec.objects))
        render(view.tracer, view.view.at(1))  # kernels load on a first render
        per_ray, per_flop = [], []
        for _ in range(REPEATS):
            traced = render(view.tracer, view.view.at(SPP))
            per_ray.append(traced.seconds / traced.rays_traced)
            frame = render_frame(
                model, box, objects, view.tracer, view.cube, view.camera, k=config.wavelets,
                weighting=config.selection, spp=1, checkerboard=config.checkerboard,
            )  # fmt: skip
            per_flop.append(frame.network_seconds / frame.network_flops)
        ray, flop = statistics.median(per_ray), statistics.median(per_flop)
        section.add(scene=name, ns_per_ray=ray * 1e9, ns_per_flop=flop * 1e9, flops_per_ray=ray / flop)
    return [section]
