"""A trained mesogan, on fur and on grass, generates slab views closer to held-out path-traced ones than
trivial baselines: in block means (colour and shading under the labels) and in the Laplacian-pyramid patch
distribution (SWD), against a black image and against the same networks untrained. And it follows its
labels (the issue's "Conditioning"): a denser label makes the views' pile more opaque and a longer one
stops rays higher, as real strands under the same labels do (fur), and a colour label changes the rendered
colour its way while density never reads it."""

from __future__ import annotations

import pytest
import torch

from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.evaluate import PROBES, generation_scores, held_out_views, structure_response
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import SlabSource, SlabSourceConfig
from workers.models.mesogan.train import fake_views, phases
from workers.runtime.samplers import open_batches
from workers.runtime.sources import SourceSpec
from workers.runtime.threads import torch_threads
from workers.runtime.training import train_phases

pytestmark = pytest.mark.slow  # trains the quick preset on fur and on grass: about a minute each


@pytest.fixture(scope="module", params=["fur", "grass"])
def trained(request):
    config = MesoganConfig.model_validate(PRESETS["quick"] | {"material": request.param})
    spec = SourceSpec(SlabSource, SlabSourceConfig(mesogan=config), 3)
    with torch_threads(1):
        torch.manual_seed(3)
        untrained = MesoGAN(config)
        torch.manual_seed(3)
        model = MesoGAN(config)
        with open_batches(spec, 0) as batches:
            train_phases(model, phases(model), batches, config.train)
    return model.eval(), untrained.eval(), spec.build()


def test_a_trained_model_beats_black_and_untrained_on_held_out_views(trained):
    model, untrained, source = trained
    with torch_threads(1):
        held_out = held_out_views(source, 8)
        scores = generation_scores(model, held_out)
        before = generation_scores(untrained, held_out)
    assert scores["block_error"] < 0.6 * scores["block_error_black"], scores
    assert scores["block_error"] < before["block_error"], (scores, before)
    assert scores["swd"] < scores["swd_black"], scores


# Fur only: quick grass at 60 steps, seed 3, spreads coverage by 0.149 against the real 0.457 (0.33 of it,
# short of the third asserted here), stop height and level within range. The default preset learns it:
# 0.85 of the real coverage spread at 300 steps, 0.98 at 1000 (seed 3, `config`).
@pytest.mark.parametrize("trained", ["fur"], indirect=True)
def test_a_trained_model_moves_geometry_with_its_structure_labels(trained):
    """Coverage of held-out views follows the density label and the height where rays stop follows the
    length label, each by a good part of what real strands under the same labels do, and at their level.
    Before the structure term (`structure_weight`), coverage was 0.76 at both ends of the density range
    against 0.08 and 0.48 for real strands; a generator that ignores its labels has no spread."""
    model, _, source = trained
    with torch_threads(1):
        r = structure_response(model, source, 8)
    # Curliness (`PROBES`) is measured but not asserted: the quick preset's 60 steps do not learn it (seed
    # 3: generated coverage spread 0.016 against 0.116 real; the default preset at 500 steps, seed 5: 0.07
    # against 0.12).
    for statistic, low, high in (PROBES["density"], PROBES["length"]):
        spread = r[f"{statistic}_{high}"] - r[f"{statistic}_{low}"]
        real_spread = r[f"{statistic}_{high}_real"] - r[f"{statistic}_{low}_real"]
        assert real_spread > 0.05, (statistic, r)  # the training data do vary with the label
        # seed 3 shows 0.59 (coverage) and 0.55 (height) of the real spread, seeds 4 and 5 0.74 to 2.1;
        # the mapping made to read a constant structure gave 0.0
        assert spread > real_spread / 3, (statistic, r)
        level = (r[f"{statistic}_{high}"] + r[f"{statistic}_{low}"]) / 2
        real_level = (r[f"{statistic}_{high}_real"] + r[f"{statistic}_{low}_real"]) / 2
        assert abs(level - real_level) < 0.15, (statistic, r)


def test_a_trained_model_renders_a_colour_label_its_way(trained):
    model, _, source = trained
    views = held_out_views(source, 8)
    red, blue = dict(views), dict(views)
    red["appearance"] = torch.tensor([0.8, 0.1, 0.1]).expand_as(views["appearance"])
    blue["appearance"] = torch.tensor([0.1, 0.1, 0.8]).expand_as(views["appearance"])
    with torch_threads(1), torch.no_grad():
        torch.manual_seed(0)
        reds = fake_views(model, red).image.mean((0, 2, 3))
        torch.manual_seed(0)
        blues = fake_views(model, blue).image.mean((0, 2, 3))
    # density never reads appearance (tests/unit/test_mesogan_networks.py checks the routing)
    assert reds[0] - reds[2] > blues[0] - blues[2] + 0.05, (reds, blues)
