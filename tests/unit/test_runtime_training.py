import math

import pytest
import torch

from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import AnalyticSource, AnalyticSourceConfig, SourceSpec
from workers.runtime.training import (
    MAIN_PHASE,
    OptimizerConfig,
    Phase,
    Progress,
    Schedule,
    TrainConfig,
    TrainingDiverged,
    TrainResult,
    train,
    train_phases,
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


def assert_same_weights(expected: torch.nn.Module, actual: torch.nn.Module) -> None:
    for (name, a), b in zip(expected.state_dict().items(), actual.state_dict().values(), strict=True):
        assert torch.equal(a, b), name


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


@pytest.mark.parametrize("fused", [False, True])
def test_resume_equals_an_uninterrupted_run_bit_for_bit(tmp_path, fused):
    config = CONFIG.model_copy(update={"fused": fused})
    reference = small_mlp()
    reference_store = CheckpointStore(str(tmp_path / "reference"), keep=10)
    losses = []
    train(reference, mse, InProcessBatches(SPEC), config, reference_store, lambda e: losses.append(e.loss))

    resumed = small_mlp()
    store = CheckpointStore(str(tmp_path / "resumed"), keep=2)
    with pytest.raises(Interrupted):  # a crash at step 10: the latest checkpoint is step 8
        train(resumed, mse, InProcessBatches(SPEC), config, store, interrupt_at(10))
    assert store.latest() == 8
    resumed = small_mlp(seed=99)  # a fresh process would build the model from scratch
    resumed_losses = []
    train(resumed, mse, InProcessBatches(SPEC), config, store, lambda e: resumed_losses.append(e.loss))

    assert resumed_losses == losses[8:]
    assert_same_weights(reference, resumed)
    assert store.load(12) == reference_store.load(12)  # weights, Adam's state, RNG states, loop position


class ShuffledBatches(InProcessBatches):
    """A `ResumableStream`: which batch comes next depends on a counter the stream keeps, not only on
    its position (as an active-exploration trainer's choices depend on its chains)."""

    def __init__(self, spec: SourceSpec) -> None:
        super().__init__(spec)
        self.drawn = 0

    def __next__(self):
        self.drawn += 1
        self.position += 1
        return self.source.batch(self.drawn * 7 % 5)

    def state_files(self) -> dict[str, bytes]:
        return {"stream-drawn": str(self.drawn).encode()}

    def restore(self, files: dict[str, bytes]) -> None:
        self.drawn = int(files["stream-drawn"])


def test_a_streams_own_state_is_checkpointed_and_restored(tmp_path):
    reference = small_mlp()
    train(reference, mse, ShuffledBatches(SPEC), CONFIG, CheckpointStore(str(tmp_path / "reference")))
    store = CheckpointStore(str(tmp_path / "resumed"))
    with pytest.raises(Interrupted):
        train(small_mlp(), mse, ShuffledBatches(SPEC), CONFIG, store, interrupt_at(10))
    assert store.load(8)["stream-drawn"] == b"8"
    resumed = small_mlp(seed=99)
    train(resumed, mse, ShuffledBatches(SPEC), CONFIG, store)
    assert_same_weights(reference, resumed)


def test_a_streams_files_must_be_named_as_its_own(tmp_path):
    class Stray(ShuffledBatches):
        def state_files(self) -> dict[str, bytes]:
            return {"loop.json": b"{}"}

    with pytest.raises(ValueError, match="stream-"):
        train(small_mlp(), mse, Stray(SPEC), CONFIG, CheckpointStore(str(tmp_path)))


def test_one_phase_is_the_textbook_adam_loop_bit_for_bit():
    """The loop adds checkpoints, progress and checks around plain Adam, and changes none of its arithmetic
    (the phase machinery included): the same weights and losses as a hand-written loop, on CPU."""
    trained, losses = small_mlp(), []
    train(trained, mse, InProcessBatches(SPEC), CONFIG, on_progress=lambda e: losses.append(e.loss))

    model, source, textbook_losses = small_mlp(), SPEC.build(), []
    adam = torch.optim.Adam(model.parameters(), betas=CONFIG.betas, eps=CONFIG.eps)
    for step in range(CONFIG.steps):
        for group in adam.param_groups:
            group["lr"] = CONFIG.schedule.at(step, CONFIG.steps)
        loss = mse(model, source.batch(step))
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), CONFIG.grad_clip_norm)
        adam.step()
        adam.zero_grad()
        textbook_losses.append(loss.item())

    assert losses == textbook_losses
    assert_same_weights(model, trained)


def test_checkpoint_records_where_the_sampler_stands(tmp_path):
    store = CheckpointStore(str(tmp_path), keep=1)
    train(small_mlp(), mse, InProcessBatches(SPEC), CONFIG.model_copy(update={"steps": 4}), store)
    files = store.load(4)
    model = small_mlp()
    optimizers = {MAIN_PHASE: torch.optim.Adam(model.parameters())}
    scalers = {MAIN_PHASE: torch.amp.GradScaler("cpu", enabled=False)}
    loop = training_state.decode(files, model, optimizers, scalers)
    assert (loop.step, loop.batch_position) == (4, 4)
    assert math.isfinite(loop.best_loss)
    assert loop.losses.keys() == {MAIN_PHASE} and loop.best_loss <= loop.losses[MAIN_PHASE]
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

    with pytest.raises(TrainingDiverged, match="step 3: main loss is nan") as error:
        train(small_mlp(), nan_at_step_3, InProcessBatches(SPEC), CONFIG)
    assert (error.value.step, error.value.tensor) == (3, "main loss")


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
    training_state.decode_optimizer(store.load(4), MAIN_PHASE, optimizer)
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


class ToyGan(torch.nn.Module):
    """A generator from the source's points to fake targets, and a discriminator telling fake from real."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        torch.manual_seed(seed)
        self.generator = torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3))
        self.discriminator = torch.nn.Sequential(
            torch.nn.Linear(3, 16), torch.nn.Dropout(0.1), torch.nn.ReLU(), torch.nn.Linear(16, 1)
        )


def real_or_fake_loss(logits: torch.Tensor, real: bool) -> torch.Tensor:
    labels = torch.full_like(logits, float(real))
    return torch.nn.functional.binary_cross_entropy_with_logits(logits, labels)


def discriminator_loss(model: ToyGan, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    fake = model.generator(batch["inputs"]).detach()
    real_logits = model.discriminator(batch["targets"])
    return real_or_fake_loss(real_logits, True) + real_or_fake_loss(model.discriminator(fake), False)


def generator_loss(model: ToyGan, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """The non-saturating loss: it backpropagates through the discriminator into the generator."""
    return real_or_fake_loss(model.discriminator(model.generator(batch["inputs"])), True)


GENERATOR_EVERY = 3  # three discriminator updates per generator update
GAN_CONFIG = CONFIG.model_copy(
    update={
        "optimizers": {
            "discriminator": OptimizerConfig(
                schedule=Schedule(lr=4e-3, kind="exponential", decay_rate=0.5, decay_steps=10),
                betas=(0.5, 0.9),
            ),
            "generator": OptimizerConfig(schedule=Schedule(lr=1e-3), betas=(0.5, 0.99), grad_clip_norm=0.5),
        }
    }
)


def gan_phases(model: ToyGan) -> list[Phase]:
    return [
        Phase("discriminator", discriminator_loss, model.discriminator.parameters()),
        Phase("generator", generator_loss, model.generator.parameters(), every=GENERATOR_EVERY),
    ]


def textbook_gan(steps: int) -> tuple[ToyGan, list[dict[str, float]]]:
    """The DCGAN-style loop, written out: each network's Adam zeroes its gradients before its update."""
    model, source = ToyGan(), SPEC.build()
    history, losses = [], {}
    updates = [
        ("discriminator", discriminator_loss, model.discriminator, 1),
        ("generator", generator_loss, model.generator, GENERATOR_EVERY),
    ]
    adams = {}
    for name, _, network, _ in updates:
        config = GAN_CONFIG.optimizers[name]
        adams[name] = torch.optim.Adam(network.parameters(), betas=config.betas, eps=config.eps)
    for step in range(steps):
        batch = source.batch(step)
        for name, loss_fn, network, every in updates:
            if step % every:
                continue
            config, adam = GAN_CONFIG.optimizers[name], adams[name]
            adam.zero_grad()
            for group in adam.param_groups:
                group["lr"] = config.schedule.at(step, steps)
            loss = loss_fn(model, batch)
            loss.backward()
            if config.grad_clip_norm is not None:
                torch.nn.utils.clip_grad_norm_(network.parameters(), config.grad_clip_norm)
            adam.step()
            losses[name] = loss.item()
        history.append(dict(losses))
    return model, history


def test_alternating_phases_are_the_textbook_gan_loop_bit_for_bit():
    model, events = ToyGan(), []
    train_phases(model, gan_phases(model), InProcessBatches(SPEC), GAN_CONFIG, on_progress=events.append)
    expected_model, expected_losses = textbook_gan(GAN_CONFIG.steps)
    assert [e.losses for e in events] == expected_losses
    assert all(e.loss == sum(e.losses.values()) for e in events)
    assert [e.lr for e in events] == [
        GAN_CONFIG.optimizers["discriminator"].schedule.at(s, GAN_CONFIG.steps)
        for s in range(GAN_CONFIG.steps)
    ]
    assert_same_weights(expected_model, model)


def test_the_generator_phase_moves_the_generator_through_the_discriminator_and_only_it():
    model = ToyGan()
    discriminator_before = model.discriminator.state_dict()
    generator_before = [p.detach().clone() for p in model.generator.parameters()]
    generator_only = [Phase("generator", generator_loss, model.generator.parameters())]
    train_phases(
        model,
        generator_only,
        InProcessBatches(SPEC),
        GAN_CONFIG.model_copy(update={"steps": 2, "optimizers": {}}),
    )
    assert all(
        torch.equal(a, b)
        for a, b in zip(discriminator_before.values(), model.discriminator.state_dict().values(), strict=True)
    )
    assert not any(
        torch.equal(a, b) for a, b in zip(generator_before, model.generator.parameters(), strict=True)
    )
    assert all(p.grad is None for p in model.parameters())


def test_gan_resume_equals_an_uninterrupted_run_bit_for_bit(tmp_path):
    reference = ToyGan()
    reference_store = CheckpointStore(str(tmp_path / "reference"), keep=10)
    events: list[Progress] = []
    train_phases(
        reference, gan_phases(reference), InProcessBatches(SPEC), GAN_CONFIG, reference_store, events.append
    )

    resumed = ToyGan()
    store = CheckpointStore(str(tmp_path / "resumed"), keep=2)
    with pytest.raises(Interrupted):  # the latest checkpoint, step 8, falls between two generator updates
        train_phases(
            resumed, gan_phases(resumed), InProcessBatches(SPEC), GAN_CONFIG, store, interrupt_at(10)
        )
    assert store.latest() == 8 and 8 % GENERATOR_EVERY != 0
    resumed = ToyGan(seed=99)
    resumed_events: list[Progress] = []
    train_phases(
        resumed, gan_phases(resumed), InProcessBatches(SPEC), GAN_CONFIG, store, resumed_events.append
    )

    assert [(e.loss, e.losses) for e in resumed_events] == [(e.loss, e.losses) for e in events[8:]]
    assert_same_weights(reference, resumed)
    final = store.load(12)
    assert final == reference_store.load(12)
    assert {
        *training_state.optimizer_files("generator"),
        *training_state.optimizer_files("discriminator"),
    } < final.keys()


def test_divergence_names_the_phase_whose_loss_went_bad():
    calls = []

    def generator_loss_nan_at_its_third_update(model, batch):  # at step 2 * GENERATOR_EVERY
        calls.append(None)
        loss = generator_loss(model, batch)
        return loss * math.nan if len(calls) == 3 else loss

    model = ToyGan()
    discriminator, _ = gan_phases(model)
    generator = Phase("generator", generator_loss_nan_at_its_third_update, model.generator.parameters(), 3)
    with pytest.raises(TrainingDiverged, match="step 6: generator loss is nan") as error:
        train_phases(model, [discriminator, generator], InProcessBatches(SPEC), GAN_CONFIG)
    assert error.value.tensor == "generator loss"


def test_phases_and_their_optimizers_are_checked_by_name():
    model = ToyGan()
    phases = gan_phases(model)
    with pytest.raises(ValueError, match=r"config.optimizers names \['genrator'\]"):
        train_phases(
            model,
            phases[:1],
            InProcessBatches(SPEC),
            CONFIG.model_copy(update={"optimizers": {"genrator": OptimizerConfig()}}),
        )
    with pytest.raises(ValueError, match="distinct phase names"):
        train_phases(model, [phases[0], phases[0]], InProcessBatches(SPEC), CONFIG)
    with pytest.raises(ValueError, match="identifier"):
        Phase("../escape", mse)
    with pytest.raises(ValueError, match="every"):
        Phase("generator", generator_loss, every=0)


def test_a_phase_not_named_in_optimizers_takes_the_loops_own_settings():
    assert GAN_CONFIG.optimizer("generator") == GAN_CONFIG.optimizers["generator"]
    default = GAN_CONFIG.optimizer(MAIN_PHASE)
    assert (default.schedule, default.betas, default.grad_clip_norm) == (CONFIG.schedule, CONFIG.betas, 1.0)
