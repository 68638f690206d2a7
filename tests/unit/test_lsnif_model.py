"""LSNIF's pieces on a small instanced scene: plan, encoder, training signal, intersector, artifact."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.models.lsnif import artifact
from workers.models.lsnif.config import PRESETS, LsnifConfig
from workers.models.lsnif.encoding import VoxelGridEncoding, occupied_vertices
from workers.models.lsnif.network import STORAGE_DTYPE, LsnifObject
from workers.models.lsnif.plan import EMBREE, LSNIF, choose_objects, plan
from workers.models.lsnif.sampling import (
    ObjectRaySource,
    ObjectReference,
    ObjectSourceConfig,
    prepare_object,
    training_rays,
)
from workers.models.lsnif.train import lsnif_loss
from workers.nn.configs import HashGridConfig
from workers.nn.encodings.grid import pytorch_path_on_cpu
from workers.nn.encodings.sparse_hashgrid import SparseHashGrid
from workers.render.integrator import PathTracer
from workers.render.materials import MaterialTable
from workers.render.voxels import boundary_points
from workers.runtime.pipeline import round_to_storage
from workers.scene.format.spec import SceneObject, SphereShape, Transform
from workers.scene.generators.builtin import cornell_box
from workers.scene.geometry.compile import compile_scene
from workers.scene.geometry.mesh import MeshData
from workers.scene.portability.reference import SceneRef

QUICK = LsnifConfig.model_validate({**PRESETS["quick"], "min_triangles": 1000})


def instanced_scene():
    scene = cornell_box()
    ball = SceneObject(
        name="ball",
        shape=SphereShape(radius=0.3, subdivisions=4),
        material="white",
        instances=[
            Transform(translate=(-0.4, -0.6, 0.2)),
            Transform(translate=(0.4, -0.5, -0.3), rotate=(30, 45, 0), scale=(1.5, 0.7, 1.0)),
        ],
    )
    return scene.model_copy(update={"objects": [*scene.objects, ball]})


@pytest.fixture(scope="module")
def compiled():
    return compile_scene(instanced_scene())


def test_plan_keeps_small_objects_and_emitters_on_embree_and_trains_instances_once():
    scene = instanced_scene()
    choices = {c.name: c for c in choose_objects(SceneRef(scene), QUICK)}
    assert choices["ball"].choice == LSNIF and choices["ball"].instances == 2
    assert "shared by its 2 instances" in choices["ball"].reason
    assert choices["floor"].choice == EMBREE and "triangles" in choices["floor"].reason
    assert choices["light"].choice == EMBREE and "emits light" in choices["light"].reason
    result = plan(SceneRef(scene), QUICK)
    assert result.estimated_seconds > 0 and result.summary.startswith("1 network(s) for 2 instance(s)")


def test_the_report_reference_must_converge_further_than_the_preview():
    every_preset = [LsnifConfig.model_validate(preset) for preset in PRESETS.values()]
    assert all(c.reference_spp > c.evaluation_spp for c in every_preset)
    with pytest.raises(ValueError, match=r"reference_spp \(16\) must exceed evaluation_spp \(16\)"):
        LsnifConfig(evaluation_spp=16, reference_spp=16)


def test_presets_change_the_sizes_not_the_networks_shape():
    quick, default = (LsnifConfig.model_validate(PRESETS[name]) for name in ("quick", "default"))
    assert (quick.grid.levels, quick.grid.features_per_level, quick.mlp.activation) == (2, 3, "leaky_relu")
    assert (quick.grid.base_resolution, quick.grid.log2_table_size, quick.mlp.width) == (32, 14, 64)
    assert (default.grid.base_resolution, default.grid.log2_table_size, default.mlp.width) == (64, 17, 128)


def test_encoder_stores_only_vertices_near_occupied_voxels_and_folds_to_the_table_size(compiled):
    prepared = prepare_object(compiled, len(compiled.objects) - 1, 16)
    occupied = prepared.grid.occupied
    lattice = {"levels": 2, "features_per_level": 3, "base_resolution": 32, "per_level_scale": 2.0}
    big = VoxelGridEncoding(occupied, HashGridConfig(**lattice, log2_table_size=20))
    folded = VoxelGridEncoding(occupied, HashGridConfig(**lattice, log2_table_size=8))
    stored = [size for _, size in big.level_blocks]
    assert stored[0] < 33**3 and stored[1] < 65**3  # sparse: far fewer than the dense lattice
    assert [size for _, size in folded.level_blocks] == [256, 256]
    # Empty space reads exactly zero, points in occupied voxels read stored features.
    empty = torch.tensor([[0.01, 0.01, 0.01]])
    assert torch.all(big(empty) == 0)
    centre = (np.argwhere(occupied)[0] + 0.5) / occupied.shape[0]
    assert torch.all(big(torch.tensor(centre[None], dtype=torch.float32)) != 0)
    assert torch.isfinite(folded(torch.rand(100, 3))).all()
    # The dense row map finds the same rows as the parent's binary search over the sorted keys.
    searched = SparseHashGrid(occupied_vertices(occupied, big.geometry), 3, 3, 32, 2.0)
    searched.table.data.copy_(big.table.data)
    points = torch.rand(2000, 3)
    torch.testing.assert_close(big(points), searched(points), rtol=0, atol=0)
    # The CPU kernels read folded rows through the row map as the PyTorch path does.
    with pytorch_path_on_cpu():
        reference = folded(points)
    torch.testing.assert_close(folded(points), reference, rtol=1e-6, atol=1e-6)


def test_only_filled_slots_are_encoded_and_empty_ones_feed_zeros(compiled):
    prepared = prepare_object(compiled, len(compiled.objects) - 1, 16)
    torch.manual_seed(0)
    model = LsnifObject(prepared.grid, 1, QUICK)
    points = torch.rand(64, QUICK.max_points, 3)
    valid = torch.rand(64, QUICK.max_points) < 0.3
    masked = model.encoding(points) * valid[..., None]
    torch.testing.assert_close(model(points, valid), model.mlp(masked.flatten(1)))


def test_normal_labels_face_the_ray_on_both_sides_of_a_thin_surface(compiled):
    vertices = np.array([[-1.0, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # wound to face +y
    origins = np.array([[0.1, 1.0, 0.2], [0.1, -1.0, 0.2]])
    directions = np.array([[0.0, -1.0, 0.0], [0.2, 1.0, 0.1]])
    materials = MaterialTable(compiled)
    for normals in (None, np.tile([0.0, 1.0, 0.0], (4, 1))):
        reference = ObjectReference(MeshData(vertices, faces, normals), np.array([0]), materials)
        labels = reference.intersect(origins, directions)
        assert labels.hit.all()
        np.testing.assert_allclose(labels.geometric_normal, [[0, 1, 0], [0, -1, 0]], atol=1e-12)
        np.testing.assert_allclose(labels.normal, [[0, 1, 0], [0, -1, 0]], atol=1e-12)


def test_training_rays_half_on_the_surface_and_loss_is_finite_and_trainable(compiled):
    config = ObjectSourceConfig(
        scene=SceneRef(instanced_scene()),
        object_index=len(instanced_scene().objects) - 1,
        lsnif=QUICK,
    )
    source = ObjectRaySource(config, seed=3)
    batch = source.batch(0)
    again = ObjectRaySource(config, seed=3).batch(0)
    assert all(torch.equal(batch[k], again[k]) for k in batch)  # a pure function of (seed, index)
    # Rays that meet no occupied voxel are left out (certain misses), every surface ray is kept last.
    assert torch.all(batch["valid"].any(1)) and len(batch["hit"]) < QUICK.batch_size
    surface = QUICK.batch_size // 2
    assert float(batch["hit"][:-surface].mean()) > 0.3  # sphere rays that reach the voxels often hit
    assert float(batch["hit"][-surface:].mean()) == 0.0  # rays leaving a convex surface never come back
    assert torch.all((batch["distance"] >= 0) & (batch["distance"] <= 1))
    hit = batch["hit"] > 0.5
    torch.testing.assert_close(batch["normal"][hit].norm(dim=1), torch.ones(int(hit.sum())))
    torch.manual_seed(0)
    model = LsnifObject(source.prepared.grid, 1, QUICK)
    optimizer = torch.optim.Adam(model.parameters(), lr=0.01)
    losses = []
    for _ in range(15):
        loss = lsnif_loss(model, batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    assert np.isfinite(losses).all() and losses[-1] < 0.8 * losses[0]


def test_surface_rays_start_on_the_surface_and_leave_it(compiled):
    prepared = prepare_object(compiled, len(compiled.objects) - 1, 16)
    rng = np.random.default_rng(0)
    origins, directions = training_rays(prepared.grid, prepared.reference, 2000, rng)
    surface = origins[1000:]
    radius = np.linalg.norm(surface, axis=1)
    assert np.all(np.abs(radius - 0.3) < 0.01)  # on the (subdivided) sphere of radius 0.3
    assert np.all(np.sum(directions[1000:] * surface, axis=1) > 0)  # leaving a convex surface outwards


def test_predictions_are_finite_for_any_finite_ray_and_zero_directions_are_refused(compiled):
    prepared = prepare_object(compiled, len(compiled.objects) - 1, 16)
    model = LsnifObject(prepared.grid, 1, QUICK)
    rng = np.random.default_rng(1)
    origins = rng.normal(size=(500, 3)) * np.array([1e-6, 1.0, 1e6])[rng.integers(0, 3, 500), None]
    directions = rng.normal(size=(500, 3))
    directions[:50, :2] = 0.0  # axis-parallel
    directions[50:100] *= 1e-12  # tiny but non-zero
    prediction = model.predict(origins, directions)
    for value in (prediction.normal, prediction.albedo):
        assert np.isfinite(value).all()
    assert np.all(np.isfinite(prediction.t) | ~prediction.hit)
    with pytest.raises(ValueError, match="zero length"):
        model.predict(np.zeros((2, 3)), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))


class ExactBall:
    """A stand-in 'network' answering exactly (an analytic sphere): isolates the intersector's transforms."""

    def __init__(self, radius):
        self.radius = radius

    def predict(self, origins, directions):
        a = np.sum(directions * directions, 1)
        b = np.sum(origins * directions, 1)
        c = np.sum(origins * origins, 1) - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.maximum(disc, 0))
        t0, t1 = (-b - root) / a, (-b + root) / a
        t = np.where(t0 > 1e-9, t0, t1)
        hit = (disc >= 0) & (t > 1e-9)

        class Answer:
            pass

        answer = Answer()
        answer.hit, answer.t = hit, np.where(hit, t, np.inf)
        answer.normal = origins + t[:, None] * directions
        answer.albedo = np.full((len(t), 3), 0.25)
        answer.material = np.zeros(len(t), np.int64)
        return answer


def test_intersector_places_scaled_and_rotated_instances_like_embree(compiled):
    from workers.models.lsnif.intersector import NeuralInstance, NeuralIntersector

    geometry = compiled.objects[-1]
    bounds = np.array([[-0.31] * 3, [0.31] * 3])
    material = np.array([compiled.material_names.index("white")])
    instances = [
        NeuralInstance(ExactBall(0.3), bounds, m, r, material)
        for m, r in zip(geometry.instance_matrices, geometry.triangle_ranges, strict=True)
    ]
    hybrid = NeuralIntersector(compiled, instances)
    embree = PathTracer(compiled).rays
    rng = np.random.default_rng(2)
    origins = rng.uniform(-0.9, 0.9, (4000, 3))
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    ours, reference = hybrid.intersect(origins, directions), embree.intersect(origins, directions)
    ball = (reference.prim >= geometry.triangle_ranges[0][0]) & (
        reference.prim < geometry.triangle_ranges[1][1]
    )
    neural = ours.surface.where
    agree = neural == ball
    assert agree.mean() > 0.97  # the analytic sphere vs its 4-times subdivided mesh differ at silhouettes
    both = neural & ball
    np.testing.assert_allclose(ours.t[both], reference.t[both], atol=0.01)
    assert np.all(ours.surface.material[neural] == material[0])
    other = ~neural & ~ball
    # Rays that leave the instances meet the same surfaces at the same distance. Where a ray crosses an
    # edge two triangles tie, and which one Embree reports depends on the ray's exact origin.
    np.testing.assert_array_equal(ours.prim[other] >= 0, reference.prim[other] >= 0)
    met = other & (reference.prim >= 0)
    np.testing.assert_allclose(ours.t[met], reference.t[met], rtol=1e-5)
    assert (ours.prim[other] == reference.prim[other]).mean() > 0.99
    blocked = hybrid.occluded(origins, directions, np.full(4000, 0.5))
    expected = embree.occluded(origins, directions, np.full(4000, 0.5))
    assert (blocked == expected).mean() > 0.97


def test_artifact_round_trip_answers_identically(tmp_path, compiled):
    prepared = prepare_object(compiled, len(compiled.objects) - 1, 16)
    torch.manual_seed(0)
    model = round_to_storage(LsnifObject(prepared.grid, 1, QUICK), STORAGE_DTYPE).eval()
    stored = artifact.export_object(model)
    assert stored["grid.table"].dtype == np.float16 and stored["mlp.layers.0.weight"].dtype == np.float16
    assert model.size_bytes() == sum(v.nbytes for v in stored.values())  # counts what the file holds
    files = artifact.save(
        tmp_path, QUICK, {"ball": model}, {"ball": {"materials": ["white"], "instances": []}}, compiled.spec
    )
    assert set(files) == {"objects/ball.safetensors", "lsnif.json", "scene.json"}
    loaded = artifact.load(tmp_path)
    rng = np.random.default_rng(5)
    origins, directions = rng.normal(size=(300, 3)), rng.normal(size=(300, 3))
    a, b = model.predict(origins, directions), loaded.models["ball"].predict(origins, directions)
    np.testing.assert_array_equal(a.hit, b.hit)
    np.testing.assert_allclose(a.normal, b.normal)
    walk = boundary_points(prepared.grid, origins, directions, QUICK.max_points)
    assert np.array_equal(
        walk.count, boundary_points(loaded.models["ball"].grid, origins, directions, 12).count
    )


def test_albedo_labels_carry_the_vertex_colour_at_the_hit(compiled):
    vertices = np.array([[-1.0, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    colors = np.c_[(vertices[:, 0] + 1) / 2, np.ones(4), np.full(4, 0.5)]  # red grows along +x
    materials = MaterialTable(compiled)
    origins = np.array([[-0.5, 1.0, 0.2], [0.6, 1.0, -0.3]])
    directions = np.tile([0.0, -1.0, 0.0], (2, 1))
    plain, coloured = (
        ObjectReference(mesh, np.array([0]), materials).intersect(origins, directions)
        for mesh in (MeshData(vertices, faces), MeshData(vertices, faces, colors=colors))
    )
    assert (plain.albedo > 0).all()
    np.testing.assert_allclose(coloured.albedo, plain.albedo * [[0.25, 1, 0.5], [0.8, 1, 0.5]], atol=1e-12)
