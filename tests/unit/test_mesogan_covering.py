"""The mesogan material on a mesh as users bring one (untrained weights: the covering, not the look): a
mesh file without texture coordinates gets the box projection's UVs and renders through the scene ->
shell path; a shell height relative to the covered surfaces' size scales with the mesh, one in world
units does not, and the two are refused together naming the field."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from pydantic import ValidationError

from workers.models.mesogan import KIND, artifact
from workers.models.mesogan.covering import covering
from workers.models.mesogan.material import draw
from workers.models.mesogan.networks import MesoGAN
from workers.models.registry import register_materials
from workers.render.render import RenderSettings, render
from workers.scene.format.spec import MesoganMaterial
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import scene_from_dict

RELATIVE = 0.04


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A scene folder: an icosphere OBJ of radius 1 without texture coordinates (a scan has none) and an
    untrained artifact under `models/fur`."""
    folder = tmp_path_factory.mktemp("uvless")
    sphere = trimesh.creation.icosphere(subdivisions=3)
    obj = trimesh.exchange.obj.export_obj(sphere, include_normals=True, include_texture=False)
    assert "\nvt " not in obj
    (folder / "scan.obj").write_text(obj)
    config = KIND.resolve_config("quick", {})
    torch.manual_seed(0)
    artifact.save(folder / "models" / "fur", config, MesoGAN(config), get_builtin("fur_ball"))
    return folder


def scene(folder, scale: float = 1.0, **material):
    """The scan (scaled by `scale`) under the mesogan material, framed by a camera at 4 radii."""
    data = {
        "name": "scan",
        "materials": {"fur": {"type": "mesogan", "path": "models/fur", **material}},
        "objects": [
            {
                "name": "scan",
                "shape": {"type": "mesh", "path": "scan.obj"},
                "material": "fur",
                "transform": {"scale": scale},
            }
        ],
        "lights": [{"type": "directional", "direction": [-1, -1, -1], "irradiance": [3, 3, 3]}],
        "environment": {"type": "constant", "radiance": [0.3, 0.3, 0.3]},
        "camera": {"position": [0, 0, 4 * scale], "target": [0, 0, 0], "fov": 40, "width": 24, "height": 24},
    }
    return compile_scene(scene_from_dict(data), folder)


def shell_of(compiled):
    spec = compiled.spec
    return draw(compiled, {"fur": spec.materials["fur"]}, spec.camera).shell


def test_a_mesh_without_uvs_is_covered_through_a_box_projection(folder):
    compiled = scene(folder, shell_height=0.05)
    assert not compiled.uvs.any()  # the OBJ has no texture coordinates
    cover = covering(compiled, ["fur"], 0.05, KIND.resolve_config("quick", {}).texel)
    assert cover.uvs.min() >= 0 and cover.uvs.max() <= 1
    # Every triangle has its own UV area, and the frame is right-handed (u, v, normal) on every chart.
    shell = shell_of(compiled)
    centres = np.full((len(shell), 3), 1 / 3)
    tangent, bitangent, normal = shell.frame(np.arange(len(shell)), centres)
    assert (np.einsum("ij,ij->i", np.cross(tangent, bitangent), normal) > 0.99).all()

    register_materials()
    settings = RenderSettings(spp=1, width=24, height=24, seed=1)
    image = render(compiled, settings).image
    bare = render(compile_scene(compiled.spec.model_copy(update={"materials": {"fur": MesoganMaterial(
        path="models/fur").base}}), folder), settings).image  # fmt: skip
    changed = np.abs(image - bare).max(axis=2) > 0.02
    assert np.isfinite(image).all() and 0.05 < changed.mean() < 0.9, changed.mean()


def radial_thickness(shell) -> float:
    """The length a ray from outside along -x towards the centre travels inside the shell's prisms: the
    shell's height where it meets the surface head on (the sphere's vertex normals are radial)."""
    origin, direction = np.array([[100.0, 0.013, 0.021]]) * shell.base.max(), np.array([[-1.0, 0.0, 0.0]])
    found = shell.intervals(origin, direction, np.zeros(1), np.full(1, np.inf))
    first = found.enter.min()
    near = found.enter < first + 2 * (found.leave - found.enter).max()  # the near side's prisms only
    return float((found.leave[near] - found.enter[near]).sum())


def test_a_relative_shell_height_scales_with_the_mesh(folder):
    small = shell_of(scene(folder, shell_height_relative=RELATIVE))
    large = shell_of(scene(folder, 10.0, shell_height_relative=RELATIVE))
    diagonal = np.linalg.norm(np.ptp(small.base.reshape(-1, 3), 0))
    assert small.height == pytest.approx(RELATIVE * diagonal)
    assert radial_thickness(small) == pytest.approx(small.height, rel=0.02)
    assert radial_thickness(large) == pytest.approx(10 * radial_thickness(small), rel=1e-4)
    # In world units the height stays what it was, whatever the mesh's size.
    absolute = [radial_thickness(shell_of(scene(folder, s, shell_height=0.1))) for s in (1.0, 10.0)]
    assert absolute[1] == pytest.approx(absolute[0], rel=1e-4)


def test_shell_heights_are_validated_naming_the_field():
    for material, field, words in (
        ({"shell_height": 0.1, "shell_height_relative": 0.1}, "shell_height_relative", "at most one"),
        ({"shell_height_relative": 0}, "shell_height_relative", "greater than 0"),
        ({"shell_height_relative": 1.5}, "shell_height_relative", "less than or equal to 1"),
    ):
        with pytest.raises(ValidationError) as error:
            MesoganMaterial(path="models/fur", **material)
        (first,) = error.value.errors()
        assert first["loc"] == (field,) and words in first["msg"], first
