"""Every kind's plan counts a job's fixed costs (`workers.runtime.fixed_costs`), and they grow with what
they model. No training: plans only."""

from __future__ import annotations

import pytest

from workers.models.registry import get_kind, kind_names
from workers.runtime import fixed_costs as costs
from workers.runtime.fixed_costs import fixed_costs, report_view
from workers.scene.format.spec import SceneObject, SphereShape
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

EXTRA_S = 1000.0


def quick_plan(name: str, **overrides):
    kind = get_kind(name)
    config = kind.resolve_config("quick", {**kind.example.overrides, **overrides})
    return kind.plan(SceneRef(get_builtin(kind.example.scene)), config)


def fixed_item(plan):
    return next(item for item in plan.items if item.name == "fixed costs")


@pytest.fixture(scope="module")
def planned() -> dict:
    """Every kind's quick plan, made once (`prt`'s and `explore`'s trace probes)."""
    return {name: quick_plan(name) for name in kind_names()}


@pytest.mark.parametrize("name", kind_names())
def test_a_quick_plan_counts_its_fixed_costs(name, planned, monkeypatch):
    plan = planned[name]
    assert float(fixed_item(plan).choice.removesuffix(" s")) > 0
    monkeypatch.setattr(costs, "DRIVER_START_S", costs.DRIVER_START_S + EXTRA_S)
    slower = quick_plan(name)
    # the hand-off is in the estimate itself, not only in the plan's items
    assert slower.estimated_seconds - plan.estimated_seconds == pytest.approx(EXTRA_S)


@pytest.mark.parametrize("name", [n for n in kind_names() if n != "render"])
def test_a_finer_reference_costs_more_evaluation(name, planned):
    reference_spp = get_kind(name).resolve_config("quick", get_kind(name).example.overrides).reference_spp
    coarse, fine = planned[name], quick_plan(name, reference_spp=4 * reference_spp)
    assert fine.estimated_seconds > coarse.estimated_seconds
    assert fixed_item(fine).reason != fixed_item(coarse).reason  # the path segments counted


def test_evaluation_grows_with_spp_and_pixels():
    scene, config = SceneRef(get_builtin("cornell_box")), quick_config("lsnif")
    base = fixed_costs(scene, config, (report_view(32**2, 4, 300),)).evaluation
    assert fixed_costs(scene, config, (report_view(32**2, 4, 1200),)).evaluation > base
    assert fixed_costs(scene, config, (report_view(64**2, 4, 300),)).evaluation > base
    assert fixed_costs(scene, config, (report_view(32**2, 64, 300),)).evaluation > base


def test_more_triangles_cost_more_compile():
    config = quick_config("render")
    small, large = (fixed_costs(sphere_scene(n), config) for n in (2, 6))
    assert large.triangles > small.triangles
    assert large.scene > small.scene


def test_scene_files_cost_their_bytes(tmp_path):
    config = quick_config("render")
    scene = SceneRef(get_builtin("cornell_box"), tmp_path)
    empty = fixed_costs(scene, config)
    (tmp_path / "sky.exr").write_bytes(bytes(1 << 20))
    with_file = fixed_costs(scene, config)
    assert with_file.scene_bytes == empty.scene_bytes + (1 << 20)
    assert with_file.scene > empty.scene


def test_sampler_actors_add_their_start_up():
    scene = SceneRef(get_builtin("cornell_box"))
    alone = fixed_costs(scene, quick_config("lsnif", samplers=0))
    with_actors = fixed_costs(scene, quick_config("lsnif", samplers=2))
    assert alone.samplers == 0 < with_actors.samplers
    assert with_actors.seconds > alone.seconds


def quick_config(name: str, **overrides):
    return get_kind(name).resolve_config("quick", overrides)


def sphere_scene(subdivisions: int) -> SceneRef:
    spec = get_builtin("cornell_box")
    sphere = SceneObject(name="ball", shape=SphereShape(subdivisions=subdivisions), material="white")
    return SceneRef(spec.model_copy(update={"objects": [*spec.objects, sphere]}))
