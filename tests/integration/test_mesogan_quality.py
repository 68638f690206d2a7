"""A trained mesogan generates slab views closer to held-out path-traced ones than trivial baselines: in
block means (colour and shading under the labels) and in the Laplacian-pyramid patch distribution (SWD),
against a black image and against the same networks untrained."""

from __future__ import annotations

import pytest
import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.evaluate import generation_scores, held_out_views
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig
from workers.models.mesogan.train import phases
from workers.runtime.samplers import open_batches
from workers.runtime.sources import SourceSpec
from workers.runtime.threads import torch_threads
from workers.runtime.training import train_phases

pytestmark = pytest.mark.slow  # trains the quick preset: about two minutes on the loaded 2-core CPU


def test_a_trained_model_beats_black_and_untrained_on_held_out_views():
    config = MesoganConfig.model_validate(PRESETS["quick"])
    spec = SourceSpec(SlabSource, SlabSourceConfig(mesogan=config), 3)
    with torch_threads(1):
        torch.manual_seed(3)
        untrained = MesoGAN(config)
        torch.manual_seed(3)
        model = MesoGAN(config)
        with open_batches(spec, 0) as batches:
            train_phases(model, phases(model), batches, config.train)
        held_out = held_out_views(spec.build(), 8)
        trained = generation_scores(model.eval(), held_out)
        before = generation_scores(untrained.eval(), held_out)
    assert trained["block_error"] < 0.6 * trained["block_error_black"], trained
    assert trained["block_error"] < before["block_error"], (trained, before)
    assert trained["swd"] < trained["swd_black"], trained
