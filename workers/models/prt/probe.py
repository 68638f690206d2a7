"""Which objects' indirect light is worth modelling: a short probe path trace (`probe_spp` paths through
every pixel of a few training views under a white cube map) splits each object's light into direct and
indirect; an object whose indirect light is below `MIN_INDIRECT_SHARE` of its light is left to direct
lighting (its pixels get no prediction and no rows)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.models.prt.config import PrtConfig
from workers.models.prt.data import cached, cameras, tracing_key, transport_tracer
from workers.models.prt.gbuffer import surface_inputs
from workers.models.prt.transport import DIRECT, INDIRECT, trace_rows
from workers.models.prt.views import TRAIN, pixel_rays
from workers.render.sampling import luminance
from workers.scene.portability.reference import SceneRef

MIN_INDIRECT_SHARE = 0.01  # of an object's light under a white sky: below, indirect is not worth a network
PROBE_VIEWS = 3


@dataclass(frozen=True)
class ObjectChoice:
    index: int
    name: str
    modelled: bool
    indirect_share: float
    reason: str


def probe_objects(scene: SceneRef, config: PrtConfig) -> list[ObjectChoice]:
    """Every object's choice (cached per process: the plan, the method and the source ask alike)."""
    return cached(tracing_key("probe", scene, config, 0), lambda: _probe(scene, config))


def modelled_objects(scene: SceneRef, config: PrtConfig) -> tuple[int, ...]:
    return tuple(c.index for c in probe_objects(scene, config) if c.modelled)


def _probe(scene: SceneRef, config: PrtConfig, seed: int = 0) -> list[ObjectChoice]:
    tracer = transport_tracer(scene, config)
    rng = np.random.default_rng([seed, 17])
    views = cameras(scene, config)[TRAIN]
    picks = np.linspace(0, len(views) - 1, min(PROBE_VIEWS, len(views))).round().astype(int)
    n_objects = len(scene.spec.objects)
    direct, indirect = np.zeros(n_objects), np.zeros(n_objects)
    for i in picks:
        origins, directions = pixel_rays(views[i])
        seen = surface_inputs(tracer, origins, directions)
        at = np.flatnonzero(seen.hit)
        rows = trace_rows(
            tracer, origins[at], directions[at], config.probe_spp, config.cube_size, rng, config.max_depth,
            categories=(DIRECT, INDIRECT),
        )  # fmt: skip
        objects = seen.object_id[at]
        direct += np.bincount(objects, luminance(rows.direct.sum(1)), minlength=n_objects)
        indirect += np.bincount(objects, luminance(rows.indirect.sum(1)), minlength=n_objects)
    choices = []
    for index, obj in enumerate(scene.spec.objects):
        total = direct[index] + indirect[index]
        if total <= 0:
            choices.append(ObjectChoice(index, obj.name, False, 0.0, "not seen from the training views"))
            continue
        share = float(indirect[index] / total)
        modelled = share >= MIN_INDIRECT_SHARE
        verb = "modelled" if modelled else "left to direct light"
        reason = f"indirect is {100 * share:.1f}% of its light under a white sky: {verb}"
        choices.append(ObjectChoice(index, obj.name, modelled, share, reason))
    return choices
