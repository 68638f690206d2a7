"""`explore`'s plan: the variables and their dimensions, what stays static, and which variables the
camera never sees change anything, the mirrors; an uploaded scene plans and renders from its stored files."""

from __future__ import annotations

import hashlib

import pytest
import trimesh

from workers.models.explore import KIND
from workers.models.explore.source import PatchRequest, PatchSource, PatchSourceConfig
from workers.scene.format.errors import SceneError
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.io import scene_from_dict
from workers.scene.portability.reference import SceneRef
from workers.scene.portability.stored import CACHE_ENV, StoredScene

CONFIG = KIND.resolve_config("quick", {})


def test_a_variable_that_moves_an_object_out_of_sight_is_reported():
    data = get_builtin("cornell_moving_light").model_dump(mode="json")
    data["objects"].append(
        {"name": "behind", "shape": {"type": "sphere", "radius": 0.2}, "material": "white",
         "transform": {"translate": [0, 0, 6]}}
    )  # fmt: skip
    data["variables"].append({"type": "translate", "name": "behind", "object": "behind", "max": [0.5, 0, 0]})
    plan = KIND.plan(SceneRef(scene_from_dict(data)), CONFIG)
    items = {item.name: item for item in plan.items}
    assert (
        items["light"].choice == "light_position"
        and "2 dimension(s): light.x, light.z" in items["light"].reason
    )
    assert items["behind"].choice == "unseen" and "sees no change" in items["behind"].reason
    assert "small_box" in items["static"].reason and "light" not in items["static"].reason.split("moves ")[1]
    assert plan.estimated_seconds > 0 and "3 dimension(s)" in plan.summary


def test_a_scene_without_variables_is_refused_naming_the_field():
    with pytest.raises(SceneError) as error:
        KIND.plan(SceneRef(get_builtin("cornell_box")), CONFIG)
    assert error.value.field == "variables"


def test_the_uniform_baseline_is_planned_at_twice_the_training_time():
    """Twice the training, and the job's fixed costs once."""
    scene = SceneRef(get_builtin("cornell_moving_light"))
    alone = KIND.plan(scene, CONFIG)
    compared = KIND.plan(scene, KIND.resolve_config("quick", {"uniform_baseline": True}))
    assert "baseline" not in {item.name for item in alone.items}
    choices = {item.name: item.choice for item in compared.items}
    assert choices["baseline"].startswith("uniform")
    fixed = float(choices["fixed costs"].removesuffix(" s"))
    assert fixed > 0 and choices["fixed costs"] == {i.name: i.choice for i in alone.items}["fixed costs"]
    training = alone.estimated_seconds - fixed
    assert compared.estimated_seconds - fixed == pytest.approx(2 * training, abs=0.1)


def test_the_estimate_counts_the_renders_that_reuse_leaves():
    """p_s decides how many steps render patches: the paper's beta (p_s 0.99) renders a tenth as often as
    the default's (0.9), and a beta of 30 (p_s 1 - 1e-13) only in the bootstrap."""
    scene = SceneRef(get_builtin("cornell_moving_light"))
    seconds = {
        beta: KIND.plan(scene, KIND.resolve_config("default", {"reuse_beta": beta})).estimated_seconds
        for beta in (2.2, 4.6, 30.0)
    }
    assert seconds[2.2] > seconds[4.6] > seconds[30.0]


def test_mirrors_are_reported_learned_or_followed():
    scene = SceneRef(get_builtin("mirror_variable"))
    learned = KIND.plan(scene, KIND.resolve_config("quick", {"mirror_bounces": 0}))
    learned = {item.name: item for item in learned.items}["mirrors"]
    assert learned.choice == "learned by the network" and learned.reason.startswith("mirror:")
    followed = KIND.plan(scene, CONFIG)  # the default follows one bounce
    assert {item.name: item.choice for item in followed.items}["mirrors"].startswith("followed")
    assert "mirrors" not in {
        item.name for item in KIND.plan(SceneRef(get_builtin("cornell_moving_light")), CONFIG).items
    }
    # a sphere whose roughness variable reaches a mirror's finish is followed at that end
    varied = {item.name: item for item in KIND.plan(SceneRef(get_builtin("cornell_variable")), CONFIG).items}
    assert varied["mirrors"].reason.startswith("sphere:")


def test_an_uploaded_scene_plans_and_renders_patches_from_its_stored_files(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "node-cache"))
    mesh = tmp_path / "blob" / "torus.obj"
    mesh.parent.mkdir()
    trimesh.creation.torus(0.3, 0.1).export(mesh)
    data = get_builtin("cornell_moving_light").model_dump(mode="json")
    data["objects"].append(
        {"name": "torus", "shape": {"type": "mesh", "path": "torus.obj"}, "material": "white",
         "transform": {"translate": [0.3, -0.6, 0.2]}}
    )  # fmt: skip
    data["variables"].append({"type": "translate", "name": "torus", "object": "torus", "max": [0.3, 0, 0]})
    digest = "sha256:" + hashlib.sha256(mesh.read_bytes()).hexdigest()
    stored = StoredScene(key="2" * 64, files={"torus.obj": {"url": str(mesh), "digest": digest}})
    scene = SceneRef(scene_from_dict(data), stored=stored)  # a worker's reference: no local folder
    assert "torus" in {item.name for item in KIND.plan(scene, CONFIG).items}
    source = PatchSource(PatchSourceConfig(scene, CONFIG), seed=0)
    patch = source.render(PatchRequest((0.5, 0.5, 0.5), CONFIG.resolution_start, 0, 0, seed=1))
    assert patch["target"].shape == (CONFIG.patch, CONFIG.patch, 3)
