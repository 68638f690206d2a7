"""How good and how cheap a trained LSNIF object is: the figures the issue's report asks for.

Held-out rays come from the training distribution with a seed no training batch uses. The BVH size is
estimated for the paper's uncompressed 4-wide BVH (Table 1, "BVH A"; triangles not counted) two ways:
from its stated layout with every leaf full (two triangles per 128-byte leaf plus 4-wide 128-byte
internal nodes: 85 bytes per triangle, a lower bound), and at the 140 bytes per triangle that Table 1's
own figures imply (0.8 GB for 5.7M, 2.5 GB for 18.2M, 2.9 GB for 20.5M, 3.8 GB for 27.0M triangles),
i.e. leaves that hold 1.2 triangles on average.

`compare_images` path-traces the report's view with LSNIF for secondary and shadow rays and with Embree
alone; frames are timed on one render thread each.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from workers.models.lsnif.intersector import NeuralIntersector
from workers.models.lsnif.network import LsnifObject
from workers.models.lsnif.sampling import PreparedObject, training_rays
from workers.nn.metrics import flip
from workers.render.integrator import PathTracer
from workers.render.render import render
from workers.render.voxels import boundary_points
from workers.runtime.view import PathTracedView

HELD_OUT_SEED = 2**31 - 1
BVH_NODE_BYTES = 128
BVH_WIDTH = 4
TRIANGLES_PER_LEAF = 2


PAPER_TABLE1_BYTES_PER_TRIANGLE = 140


def bvh_bytes_estimate(triangles: int) -> int:
    """The layout's lower bound: full two-triangle leaves."""
    leaves = -(-triangles // TRIANGLES_PER_LEAF)
    internal = max(-(-(leaves - 1) // (BVH_WIDTH - 1)), 1)
    return (leaves + internal) * BVH_NODE_BYTES


def bvh_bytes_paper_table1(triangles: int) -> int:
    """What the paper's Table 1 reports for BVH A at this triangle count."""
    return PAPER_TABLE1_BYTES_PER_TRIANGLE * triangles


@dataclass
class HeldOut:
    """Held-out figures of one object. A mean over an empty set is NaN, never a perfect 0: a model that
    never hits has no normal error to report, not a zero one."""

    occlusion_accuracy: float
    occlusion_accuracy_in_voxels: float  # on the rays that meet an occupied voxel (the network's work)
    hit_rate: float  # fraction of rays the model reports a hit for ...
    reference_hit_rate: float  # ... and Embree does: "always miss" scores 1 - this in occlusion accuracy
    normal_error_deg: float  # mean angle between predicted and reference normals where both hit
    distance_error: float  # mean |t - t_ref| / box diagonal where both hit
    lsnif_rays_per_s: float
    embree_rays_per_s: float


def held_out(model: LsnifObject, prepared: PreparedObject, n: int) -> HeldOut:
    rng = np.random.default_rng(HELD_OUT_SEED)
    origins, directions = training_rays(prepared.grid, prepared.reference, n, rng)
    labels = prepared.reference.intersect(origins, directions)
    start = time.perf_counter()
    prediction = model.predict(origins, directions)
    lsnif_seconds = time.perf_counter() - start
    start = time.perf_counter()
    prepared.reference.rays.intersect(origins, directions)
    embree_seconds = time.perf_counter() - start
    reach = boundary_points(prepared.grid, origins, directions, model.max_points).count > 0
    correct = prediction.hit == labels.hit
    both = prediction.hit & labels.hit
    cosine = np.clip(np.sum(prediction.normal[both] * labels.normal[both], axis=1), -1.0, 1.0)
    diagonal = float(np.linalg.norm(prepared.grid.hi - prepared.grid.lo))
    return HeldOut(
        occlusion_accuracy=_mean(correct),
        occlusion_accuracy_in_voxels=_mean(correct[reach]),
        hit_rate=_mean(prediction.hit),
        reference_hit_rate=_mean(labels.hit),
        normal_error_deg=_mean(np.degrees(np.arccos(cosine))),
        distance_error=_mean(np.abs(prediction.t[both] - labels.t[both])) / diagonal,
        lsnif_rays_per_s=n / max(lsnif_seconds, 1e-9),
        embree_rays_per_s=n / max(embree_seconds, 1e-9),
    )


def _mean(values: np.ndarray) -> float:
    """The mean, NaN (without numpy's warning) over no values."""
    return float(np.mean(values)) if values.size else float("nan")


@dataclass
class ImageComparison:
    flip: float
    flip_noise_floor: float  # FLIP of Embree against Embree with another seed: what noise alone explains
    lsnif_seconds: float
    embree_seconds: float
    lsnif_image: np.ndarray
    embree_image: np.ndarray


def compare_images(view: PathTracedView, intersector: NeuralIntersector) -> ImageComparison:
    """FLIP of a path-traced image whose secondary and shadow rays use LSNIF against pure Embree, at the
    view's samples per pixel and seed; camera rays stay on Embree in both (the paper rasterises them).

    Where LSNIF changes a path, the two images' noise decorrelates, so at low spp part of the FLIP is
    Monte Carlo noise: the noise floor (Embree against itself with another seed) says how much; LSNIF's
    FLIP can also fall below it where most paths stay the same."""
    settings = view.settings
    pure = view.frame(settings.spp)
    embree = PathTracer(view.scene)
    other_seed = render(embree, settings.model_copy(update={"seed": settings.seed + 1})).image
    hybrid = PathTracer(view.scene, intersector=intersector, primary=embree.rays)
    image = render(hybrid, settings)
    return ImageComparison(
        float(flip(pure.image, image.image)),
        float(flip(pure.image, other_seed)),
        image.seconds,
        pure.seconds,
        image.image,
        pure.image,
    )
