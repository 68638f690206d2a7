"""`prt`'s plan: a probe path trace leaves objects without measurable indirect light to direct lighting."""

from __future__ import annotations

from workers.models.registry import get_kind
from workers.scene.format import spec
from workers.scene.portability.reference import SceneRef


def convex_box() -> spec.SceneSpec:
    return spec.SceneSpec(
        materials={"m": spec.Conductor(roughness=0.3)},
        objects=[spec.SceneObject(name="box", shape=spec.BoxShape(), material="m")],
        environment=spec.ConstantBackground(),
        camera=spec.Camera(position=(2.0, 1.5, 3.0), width=16, height=16),
    )


def test_a_convex_object_alone_is_left_to_direct_light_and_the_plan_says_why():
    kind = get_kind("prt")
    plan = kind.plan(SceneRef(convex_box()), kind.resolve_config("quick", {}))
    items = {item.name: item for item in plan.items}
    assert items["box"].choice == "direct only" and "indirect is 0.0%" in items["box"].reason
    assert {"lighting", "hash grid box", "memory", "ground truth", "frame"} <= set(items)
    assert plan.summary.startswith("indirect light of 0 of 1 objects") and plan.estimated_seconds > 0


def test_the_plan_says_the_default_job_counts_its_frame_s_cost_and_a_fixed_count_is_kept():
    kind = get_kind("prt")
    counted = plan_items(kind, "default", {})["frame"]
    assert counted.choice == "direct light at 4, 8, 16, 32, 64 spp, counted"
    assert "beats path tracing" in counted.reason and "not time" in counted.reason
    fixed = plan_items(kind, "default", {"evaluation_spp": 8, "checkerboard": False})["frame"]
    assert fixed.choice == "direct light at 8 spp" and fixed.reason.endswith("the network at every pixel")


def plan_items(kind, preset: str, overrides: dict) -> dict:
    plan = kind.plan(SceneRef(convex_box()), kind.resolve_config(preset, overrides))
    return {item.name: item for item in plan.items}


def test_the_estimate_charges_wider_grid_features():
    """Training's share of the estimate grows with M (1.85x from M = 16 to 64, as measured)."""
    kind = get_kind("prt")
    estimate = {
        features: kind.plan(
            SceneRef(convex_box()), kind.resolve_config("quick", {"grid": {"features_per_level": features}})
        ).estimated_seconds
        for features in (2, 8)
    }
    assert estimate[8] > estimate[2]


def test_the_estimate_charges_a_wider_f():
    """Training's share of the estimate grows with f's width (a step 2.2x from 64 to 128, as measured)."""
    kind = get_kind("prt")
    estimate = {
        width: kind.plan(
            SceneRef(convex_box()), kind.resolve_config("quick", {"mlp": {"width": width, "depth": 1}})
        ).estimated_seconds
        for width in (32, 128)
    }
    assert estimate[128] > estimate[32]
