"""Patches asked of Ray sampler actors (`RenderPool`) are the ones rendered in process, in the order asked,
with at most `max_in_flight` outstanding, and a killed actor is replaced without changing them."""

from __future__ import annotations

import pytest
import ray
import torch

from workers.models.explore import KIND
from workers.models.explore.source import PatchRequest, PatchSource, PatchSourceConfig
from workers.runtime.samplers import InProcessRenders, RenderPool
from workers.runtime.sources import SourceSpec
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

CONFIG = KIND.resolve_config("quick", {"spp": 2})
SPEC = SourceSpec(PatchSource, PatchSourceConfig(SceneRef(get_builtin("cornell_moving_light")), CONFIG), 3)
REQUESTS = [PatchRequest((0.1 * i, 0.9 - 0.1 * i), 16, i % 8, (2 * i) % 8, seed=i) for i in range(6)]


def assert_same(actual, expected) -> None:
    assert len(actual) == len(expected)
    for a, b in zip(actual, expected, strict=True):
        assert all(torch.equal(a[k], b[k]) for k in b)


@pytest.mark.slow  # a Ray cluster of its own; the explore job tests cover the in-process renders
def test_actors_render_the_in_process_patches_and_survive_a_kill(ray_cluster):
    expected = InProcessRenders(SPEC).map(REQUESTS)
    with RenderPool(SPEC, actors=2, max_in_flight=2) as pool:
        assert_same(pool.map(REQUESTS), expected)
        victim = pool.actors[1]
        ray.kill(victim, no_restart=True)
        assert_same(pool.map(REQUESTS), expected)
        assert pool.replacements == 1 and victim not in pool.actors
        made = sum(ray.get([actor.produced.remote() for actor in pool.actors]))
        assert made <= 2 * len(REQUESTS)
