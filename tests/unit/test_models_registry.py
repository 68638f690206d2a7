import pytest
from pydantic import ValidationError

from workers.models.registry import PRESET_NAMES, Kind, UnknownKind, get_kind, kind_names
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef


@pytest.fixture(scope="module")
def render():
    return get_kind("render")


def test_every_registered_kind_satisfies_the_protocol_and_has_the_three_presets():
    assert "render" in kind_names()
    for name in kind_names():
        kind = get_kind(name)
        assert isinstance(kind, Kind)
        assert kind.name == name
        assert set(PRESET_NAMES) <= set(kind.presets)
        assert kind.config_model.model_config.get("extra") == "forbid"


def test_an_unknown_kind_is_a_key_error_listing_the_known_kinds():
    with pytest.raises(KeyError) as raised:
        get_kind("nerf")
    assert isinstance(raised.value, UnknownKind)
    assert "'nerf'" in str(raised.value)
    assert "render" in str(raised.value)


def test_presets_resolve_to_growing_renders(render):
    quick, default, paper = (render.resolve_config(name, {}) for name in PRESET_NAMES)
    assert (quick.width, quick.height, quick.spp) == (64, 64, 16)
    assert (default.width, default.height, default.spp) == (256, 256, 256)
    assert (paper.width, paper.height, paper.spp) == (1024, 1024, 4096)
    assert quick.num_gpus == 0


def test_overrides_replace_preset_values(render):
    config = render.resolve_config("quick", {"spp": 4, "aovs": False})
    assert (config.width, config.spp, config.aovs) == (64, 4, False)


def test_an_unknown_preset_names_the_known_ones(render):
    with pytest.raises(ValueError, match="known presets: quick, default, paper"):
        render.resolve_config("huge", {})


@pytest.mark.parametrize(("overrides", "field"), [({"spp": 0}, "spp"), ({"sppp": 8}, "sppp")])
def test_a_bad_override_is_a_validation_error_naming_the_field(render, overrides, field):
    with pytest.raises(ValidationError) as raised:
        render.resolve_config("quick", overrides)
    assert [error["loc"] for error in raised.value.errors()] == [(field,)]


def test_the_plan_explains_every_item_and_grows_with_the_preset(render):
    scene = get_builtin("cornell_box")
    plans = [render.plan(SceneRef(scene), render.resolve_config(name, {})) for name in PRESET_NAMES]
    for plan in plans:
        assert {item.name for item in plan.items} >= {"image", "passes", "tiles", "samplers"}
        assert all(item.choice and item.reason for item in plan.items)
        assert plan.summary
    quick, default, paper = (plan.estimated_seconds for plan in plans)
    assert 0 < quick < default < paper
    estimate = next(item for item in plans[0].items if item.name == "estimate")
    assert "rays/s per core" in estimate.reason


def test_every_kind_config_names_samplers_and_gpus_alike(render):
    config = render.resolve_config("quick", {"samplers": 3, "num_gpus": 0.5})
    assert (config.samplers, config.num_gpus) == (3, 0.5)
