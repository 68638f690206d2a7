"""The structure a preset renders on the mesh lies where training draws its structure labels."""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.sampling import draw_instance, normalized_structure


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_presets_mesh_structure_is_inside_the_trained_labels(preset):
    config = MesoganConfig.model_validate(PRESETS[preset])
    on_mesh = normalized_structure(config.structure)
    rng = np.random.default_rng(0)
    drawn = np.stack([normalized_structure(draw_instance(config, rng).structure) for _ in range(256)])
    assert np.all((on_mesh >= 0.2) & (on_mesh <= 0.8)), on_mesh  # away from the ranges' sparse ends
    # training draws labels on both sides of it, near each: it is interpolated, never extrapolated
    assert np.all(drawn.min(0) < on_mesh - 0.1) and np.all(drawn.max(0) > on_mesh + 0.1)
    assert np.all(np.abs(drawn - on_mesh).min(0) < 0.02)
