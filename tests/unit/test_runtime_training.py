import math

import pytest
import safetensors.torch
import torch

from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SourceSpec
from workers.runtime.training import (
    Progress,
    Schedule,
    TrainConfig,
    TrainingDiverged,
    TrainResult,
    train,
)

SPEC = SourceSpec(AnalyticSource, AnalyticSourceConfig(batch_size=64), seed=11)
CONFIG = TrainConfig(
    steps=12,
    schedule=Schedule(lr=1e-2, kind="cosine", warmup_steps=3, final_lr_fraction=0.1),
    grad_clip_norm=1.0,
    checkpoint_every=4,
    progress_every=1,
)


def small_mlp(seed: int = 0) -> torch.nn.Module:
    torch.manual_seed(seed)
    return torch.nn.Sequential(
        torch.nn.Linear(3, 32), torch.nn.Dropout(0.1), torch.nn.ReLU(), torch.nn.Linear(32, 3)
    )


def mse(model: torch.nn.Module, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.nn.functional.mse_loss(model(batch["inputs"]), batch["targets"])


class Interrupted(Exception):
    pass


def interrupt_at(step: int):
    def on_progress(event: Progress) -> None:
        if event.step == step:
            raise Interrupted

    return on_progress


def test_schedules():
    warm = Schedule(lr=1.0, kind="constant", warmup_steps=4)
    assert [warm.at(s, 100) for s in range(5)] == [0.25, 0.5, 0.75, 1.0, 1.0]
    decay = Schedule(lr=1.0, kind="exponential", decay_rate=0.5, decay_steps=10)
    assert decay.at(0, 100) == 1.0
    assert decay.at(20, 100) == pytest.approx(0.25)
    cosine = Schedule(lr=2.0, kind="cosine", final_lr_fraction=0.1)
    assert cosine.at(0, 100) == 2.0
    assert cosine.at(50, 100) == pytest.approx(1.1)
    assert cosine.at(100, 100) == pytest.approx(0.2)


def test_resume_equals_an_uninterrupted_run_bit_for_bit(tmp_path):
    reference = small_mlp()
    reference_store = CheckpointStore(str(tmp_path / "reference"), keep=10)
    losses = []
    train(reference, mse, InProcessBatches(SPEC), CONFIG, reference_store, lambda e: losses.append(e.loss))

    resumed = small_mlp()
    store = CheckpointStore(str(tmp_path / "resumed"), keep=2)
    with pytest.raises(Interrupted):  # a crash at step 10: the latest checkpoint is step 8
        train(resumed, mse, InProcessBatches(SPEC), CONFIG, store, interrupt_at(10))
    assert store.latest() == 8
    resumed = small_mlp(seed=99)  # a fresh process would build the model from scratch
    resumed_losses = []
    train(resumed, mse, InProcessBatches(SPEC), CONFIG, store, lambda e: resumed_losses.append(e.loss))

    assert resumed_losses == losses[8:]
    for (name, a), b in zip(reference.state_dict().items(), resumed.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    final_reference, final_resumed = reference_store.load(12), store.load(12)
    for name in (training_state.OPTIMIZER_TENSORS_FILE, training_state.MODEL_FILE):
        expected = safetensors.torch.load(final_reference[name])
        actual = safetensors.torch.load(final_resumed[name])
        assert expected.keys() == actual.keys()
        assert all(torch.equal(expected[k], actual[k]) for k in expected), name


def test_checkpoint_records_where_the_sampler_stands(tmp_path):
    store = CheckpointStore(str(tmp_path), keep=1)
    train(small_mlp(), mse, InProcessBatches(SPEC), CONFIG.model_copy(update={"steps": 4}), store)
    files = store.load(4)
    model = small_mlp()
    loop = training_state.decode(
        files, model, torch.optim.Adam(model.parameters()), torch.amp.GradScaler("cpu", enabled=False)
    )
    assert (loop.step, loop.batch_position) == (4, 4)
    assert math.isfinite(loop.best_loss)
    assert len(loop.torch_rng) > 0


def test_progress_events_are_sensible():
    events: list[Progress] = []
    config = CONFIG.model_copy(update={"steps": 9, "progress_every": 4})
    result = train(small_mlp(), mse, InProcessBatches(SPEC), config, on_progress=events.append)
    assert [e.step for e in events] == [4, 8, 9]
    assert all(e.total_steps == 9 and math.isfinite(e.loss) and e.loss > 0 for e in events)
    assert all(e.samples_per_s > 0 and e.eta_s >= 0 for e in events)
    assert events[-1].eta_s == 0
    assert [e.lr for e in events] == [CONFIG.schedule.at(s - 1, 9) for s in (4, 8, 9)]
    assert result.steps == 9 and result.samples == 9 * 64
    assert result.best_loss <= result.final_loss


def test_combined_results_add_up_runs_made_one_after_another():
    first = TrainResult(steps=30, final_loss=0.5, best_loss=0.2, seconds=2.0, samples=300)
    resumed = TrainResult(steps=30, final_loss=math.nan, best_loss=math.nan, seconds=0.0, samples=0)
    last = TrainResult(steps=10, final_loss=0.9, best_loss=0.8, seconds=3.0, samples=200)
    both = TrainResult.combined([first, resumed, last])
    assert (both.steps, both.seconds, both.samples) == (70, 5.0, 500)
    assert (both.final_loss, both.best_loss) == (0.9, 0.2)  # the last run's final loss, the lowest best
    assert both.samples_per_s == 100.0
    assert TrainResult.combined([first]) == first
    nothing = TrainResult.combined([])
    assert (nothing.steps, nothing.seconds, nothing.samples, nothing.samples_per_s) == (0, 0.0, 0, 0.0)
    assert math.isnan(nothing.final_loss) and math.isnan(nothing.best_loss)


def test_nan_loss_stops_with_training_diverged():
    calls = []

    def nan_at_step_3(model, batch):
        calls.append(None)
        loss = mse(model, batch)
        return loss * math.nan if len(calls) == 4 else loss

    with pytest.raises(TrainingDiverged, match="step 3: loss is nan") as error:
        train(small_mlp(), nan_at_step_3, InProcessBatches(SPEC), CONFIG)
    assert (error.value.step, error.value.tensor) == (3, "loss")


class InfiniteGradient(torch.autograd.Function):
    """Identity forward, infinite gradient backward: a finite loss whose backward pass blows up."""

    @staticmethod
    def forward(ctx, x):
        return x.clone()

    @staticmethod
    def backward(ctx, grad):
        return torch.full_like(grad, math.inf)


def test_infinite_gradient_names_the_parameter():
    def finite_loss_infinite_gradient(model, batch):
        return mse(model, batch) + 0 * InfiniteGradient.apply(model[3].bias).sum()

    with pytest.raises(TrainingDiverged, match=r"step 0: gradient of 3\.bias is inf") as error:
        train(small_mlp(), finite_loss_infinite_gradient, InProcessBatches(SPEC), CONFIG)
    assert error.value.tensor == "gradient of 3.bias"


def test_parameter_groups_scale_the_scheduled_rate(tmp_path):
    model = small_mlp()
    frozen_before = model[0].weight.detach().clone()
    trained_before = model[3].weight.detach().clone()
    groups = [
        {"params": list(model[0].parameters()), "lr_scale": 0.0},
        {"params": list(model[3].parameters()), "lr_scale": 0.5},
    ]
    store = CheckpointStore(str(tmp_path), keep=1)
    train(
        model, mse, InProcessBatches(SPEC), CONFIG.model_copy(update={"steps": 4}), store, param_groups=groups
    )
    assert torch.equal(model[0].weight, frozen_before)
    assert not torch.equal(model[3].weight, trained_before)
    fresh = small_mlp()
    optimizer = torch.optim.Adam([{"params": list(fresh[i].parameters()), "lr_scale": 1.0} for i in (0, 3)])
    training_state.decode_optimizer(store.load(4), optimizer)
    assert [g["lr_scale"] for g in optimizer.param_groups] == [0.0, 0.5]


@pytest.mark.skipif(torch.cuda.is_available(), reason="on CUDA mixed precision is meant to change results")
def test_mixed_precision_is_a_no_op_on_cpu():
    results = []
    for mixed_precision in (True, False):
        model = small_mlp()
        config = CONFIG.model_copy(update={"steps": 3, "mixed_precision": mixed_precision})
        train(model, mse, InProcessBatches(SPEC), config)
        results.append(model.state_dict())
    assert all(torch.equal(results[0][k], results[1][k]) for k in results[0])
