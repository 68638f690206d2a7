import numpy as np
import pytest
import torch

from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SampleSource, SourceSpec, batch_rng

CONFIG = AnalyticSourceConfig(batch_size=256, input_dim=3, output_dim=2, samples_per_point=4)


def assert_batches_equal(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_analytic_source_is_a_sample_source():
    assert isinstance(AnalyticSource(CONFIG, seed=0), SampleSource)


def test_batch_depends_only_on_seed_and_index():
    first, second = AnalyticSource(CONFIG, seed=7), AnalyticSource(CONFIG, seed=7)
    assert_batches_equal(first.batch(3), second.batch(3))
    first.batch(0)  # what was generated before must not matter
    assert_batches_equal(first.batch(5), second.batch(5))
    assert not torch.equal(first.batch(3)["inputs"], first.batch(4)["inputs"])
    assert not torch.equal(first.batch(3)["inputs"], AnalyticSource(CONFIG, seed=8).batch(3)["inputs"])


def test_in_process_stream_yields_batches_in_index_order_and_seeks():
    spec = SourceSpec(AnalyticSource, CONFIG, seed=1)
    source = spec.build()
    stream = InProcessBatches(spec)
    for index in range(3):
        assert_batches_equal(next(stream), source.batch(index))
    stream.seek(10)
    assert_batches_equal(next(stream), source.batch(10))
    assert stream.position == 11


def test_estimates_are_unbiased_and_finite():
    config = AnalyticSourceConfig(batch_size=20_000, input_dim=2, output_dim=3, samples_per_point=8)
    source = AnalyticSource(config, seed=3)
    batch = source.batch(0)
    expected = source.expected(batch["inputs"].double().numpy())
    residual = batch["targets"].double().numpy() - expected
    assert np.isfinite(batch["targets"].numpy()).all()
    # 2u has variance 1/3; the mean of 8 has variance 1/24, scaled by expected^2 <= 4
    standard_error = np.sqrt((expected**2 / 24).mean() / residual.size)
    assert abs(residual.mean()) < 5 * standard_error
    assert residual.std() > 0.05  # the estimates are noisy, like path-traced samples


def test_negative_seed_or_index_is_rejected():
    with pytest.raises(ValueError, match="non-negative"):
        batch_rng(-1, 0)
    with pytest.raises(ValueError, match="non-negative"):
        AnalyticSource(CONFIG, seed=0).batch(-2)
