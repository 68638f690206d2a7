import time

import pytest
import ray
import torch

from workers.runtime.resources import ResourceRequest, actor_options
from workers.runtime.samplers import InProcessBatches, SamplerPool, open_batches
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SourceSpec
from workers.runtime.training import Progress, TrainConfig, train

SPEC = SourceSpec(AnalyticSource, AnalyticSourceConfig(batch_size=128, samples_per_point=8), seed=5)


def reference_batches(count: int) -> list[dict[str, torch.Tensor]]:
    stream = InProcessBatches(SPEC)
    return [next(stream) for _ in range(count)]


def assert_same_sequence(actual, expected) -> None:
    assert len(actual) == len(expected)
    for index, (a, b) in enumerate(zip(actual, expected, strict=True)):
        assert a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a), f"batch {index} differs"


def kill_and_wait(actor: ray.actor.ActorHandle, deadline_s: float = 60.0) -> None:
    """Kill `actor` and return once Ray reports it dead: `ray.kill` is asynchronous, and on a loaded
    machine a request sent right after it could still be answered by the dying actor, so no replacement
    would be needed and the test would measure the machine's load (seen in CI beside a benchmark)."""
    ray.kill(actor, no_restart=True)
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        try:
            ray.get(actor.produced.remote(), timeout=deadline_s)
        except ray.exceptions.RayActorError:
            return
        time.sleep(0.05)
    raise AssertionError(f"the killed actor still answered after {deadline_s} s")


def test_actors_produce_the_in_process_batches_in_order(ray_cluster):
    with SamplerPool(SPEC, actors=2, max_in_flight=3) as pool:
        batches = [next(pool) for _ in range(10)]
        pool.seek(4)
        after_seek = next(pool)
    assert_same_sequence(batches, reference_batches(10))
    assert_same_sequence([after_seek], reference_batches(5)[4:])


def test_a_slow_consumer_bounds_what_samplers_make(ray_cluster):
    max_in_flight = 3
    with SamplerPool(SPEC, actors=2, max_in_flight=max_in_flight) as pool:
        for consumed in range(1, 6):
            next(pool)
            time.sleep(0.3)  # ample time for the actors to run ahead if anything let them
            assert pool.in_flight <= max_in_flight
            produced = sum(ray.get([actor.produced.remote() for actor in pool.actors]))
            assert consumed < produced <= consumed + max_in_flight


def test_a_killed_sampler_is_replaced_and_the_sequence_is_unchanged(ray_cluster):
    with SamplerPool(SPEC, actors=2, max_in_flight=4) as pool:
        batches = [next(pool) for _ in range(3)]
        victim = pool.actors[0]
        kill_and_wait(victim)
        batches += [next(pool) for _ in range(9)]
        assert pool.replacements == 1
        assert victim not in pool.actors
    assert_same_sequence(batches, reference_batches(12))


def test_training_survives_a_killed_sampler_with_identical_results(ray_cluster):
    config = TrainConfig(steps=10, progress_every=1)

    def fit(batches, on_progress=None):
        torch.manual_seed(0)
        model = torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.Tanh(), torch.nn.Linear(16, 3))
        losses = []

        def record(event: Progress) -> None:
            losses.append(event.loss)
            if on_progress:
                on_progress(event)

        train(
            model,
            lambda m, b: torch.nn.functional.mse_loss(m(b["inputs"]), b["targets"]),
            batches,
            config,
            on_progress=record,
        )
        return model, losses

    reference_model, reference_losses = fit(InProcessBatches(SPEC))
    with open_batches(SPEC, samplers=2) as pool:

        def kill_a_sampler(event: Progress) -> None:
            if event.step == 4:
                kill_and_wait(pool.actors[1])

        model, losses = fit(pool, kill_a_sampler)
        assert pool.replacements == 1
    assert losses == reference_losses
    for a, b in zip(model.parameters(), reference_model.parameters(), strict=True):
        assert torch.equal(a, b)


def test_gpu_request_falls_back_on_a_cluster_without_gpus(ray_cluster):
    assert ray.cluster_resources().get("GPU", 0) == 0
    assert actor_options(ResourceRequest(cpus=1, gpus=1)) == {"num_cpus": 1}


@pytest.mark.parametrize("actors", [0, -1])
def test_a_pool_needs_an_actor(ray_cluster, actors):
    with pytest.raises(ValueError, match="at least one actor"):
        SamplerPool(SPEC, actors=actors)


def test_a_hanging_sampler_is_timed_out_replaced_and_the_sequence_is_unchanged(ray_cluster, tmp_path):
    from tests.support.hanging_source import HangingSource, HangingSourceConfig

    config = HangingSourceConfig(batch_size=128, samples_per_point=8, hang_at=3, flag=str(tmp_path / "hung"))
    spec = SourceSpec(HangingSource, config, seed=5)
    with SamplerPool(spec, actors=2, max_in_flight=4, batch_deadline_s=2.0) as pool:
        batches = [next(pool) for _ in range(8)]
        assert pool.replacements == 1  # the hung actor, killed: it never died on its own
    assert (tmp_path / "hung").exists()
    assert_same_sequence(batches, reference_batches(8))
