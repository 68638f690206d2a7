"""The `explore` kind's config (Diolatzis et al. 2022, "Active Exploration for Neural Global Illumination
of Variable Scenes", as in Diolatzis's thesis, Ch. 5 and App. A) and its presets (`presets/*.yaml`).

`default` and `quick` keep the method, shrink the sizes for a 2-core CPU, take small steps twice as wide
and render a tenth of the steps rather than a hundredth; `paper` is the authors' training command. Each
field's description says why its default, linking the measurement in docs/results/explore.md.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from workers.nn.configs import HashGridConfig, MLPConfig
from workers.runtime.kind_config import TrainedKindConfig, results_link
from workers.runtime.presets import load_presets
from workers.runtime.training import Schedule, TrainConfig

ACTIVE, UNIFORM = "active", "uniform"
evidence = partial(results_link, "explore")


class ExploreConfig(TrainedKindConfig):
    """Active exploration's knobs: the network, the Markov chains that choose its training patches, the
    resolution schedule, the reuse of stored patches and the losses."""

    samplers: int = Field(
        0,
        ge=0,
        le=1024,
        description="Ray actors rendering the patches the chains ask for; 0 renders them in the driver, "
        f"which on a 2-core CPU does not compete with the trainer {evidence('samplers')}.",
    )
    mlp: MLPConfig = Field(
        MLPConfig(width=128, depth=4, activation="leaky_relu"),
        description="The network (Sec. 5.3.2, App. A.5): position into the first layer, then `depth` layers "
        "of `width` that re-read the G-buffers and the scene variables v; 128 wide is acceptable (Fig. A.6).",
    )
    position_grid: HashGridConfig | None = Field(
        HashGridConfig(levels=8, base_resolution=8, per_level_scale=1.5, log2_table_size=14),
        description="A hash grid of the normalised position into the first layer (null: the thesis's "
        f"network); it lowered DSSIM by 17-20% at equal time {evidence('position-grid')}.",
    )
    grid_lr_scale: float = Field(30.0, gt=0, description="The grid table's learning rate over the layers'.")
    average_decay: float = Field(
        0.98,
        ge=0,
        lt=1,
        description="Per-step decay of the exponential average of the weights, which is what the job saves "
        f"and measures: it cut the weights' oscillation {evidence('average-decay')}.",
    )
    exploration: Literal["active", "uniform"] = Field(
        ACTIVE,
        description="active: greedy chains on loss x Adam step (Sec. 5.4); uniform: the baseline. Active "
        f"beat uniform on every scene and seed measured at 900 CPU s {evidence('exploration')}.",
    )
    uniform_baseline: bool = Field(
        False,
        description="Also train the uniform baseline at equal wall-clock time and compare both in the "
        "report (about twice the training time).",
    )
    patch: int = Field(16, ge=4, le=128, description=f"Side of a training patch, pixels {evidence('patch')}.")
    chains: int = Field(
        8,
        ge=1,
        le=256,
        description="Markov chains, one patch each per generation; 16 did no better "
        f"{evidence('chain-options')}.",
    )
    resolution_schedule: bool | None = Field(
        None,
        description="Grow R by the schedule (Sec. 5.5.2); None: for active exploration only, as in Table "
        f"5.3 {evidence('resolution-schedule')}.",
    )
    resolution_start: int = Field(64, ge=4, le=8192, description="R, the views' side, at the start.")
    resolution_max: int = Field(128, ge=4, le=8192, description="The largest R the schedule grows to.")
    resolution_step: int = Field(
        4, ge=0, le=1024, description="Pixels R grows by every `resolution_every` iterations."
    )
    resolution_every: int = Field(200, ge=1, description="Iterations between resolution steps.")
    mirror_bounces: int = Field(
        1,
        ge=0,
        le=8,
        description="Mirrors the G-buffers follow (0: none; thesis Fig. 5.10), so the network learns what a "
        f"mirror shows; it halved active's error on a mirror scene {evidence('mirror-bounces')}.",
    )
    spp: int = Field(32, ge=1, le=1 << 16, description="Path samples per pixel of a training patch.")
    target_pixel_samples: Literal["area", "centre"] = Field(
        "area",
        description="A patch's paths: over each pixel's area, or through its centre as its G-buffers are; "
        f"centre targets helped the chains but cost the baseline {evidence('target-pixel-samples')}.",
    )
    max_depth: int = Field(5, ge=1, le=64, description="Path segments of a training patch.")
    train_rejected: bool = Field(
        True,
        description="Train on a rejected proposal beside the chain's state; dropping them raised DSSIM by "
        f"6-16% {evidence('train-rejected')}.",
    )
    large_step_probability: float = Field(
        0.3,
        gt=0,
        le=1,
        description=f"p_LS of Eq. 5.1; 0.5 and 0.6 did no better {evidence('chain-options')}.",
    )
    small_step_min: float = Field(
        2 / 25,
        gt=0,
        lt=0.5,
        description="s1, the smallest small-step magnitude: twice the thesis's, better in every run that "
        f"compared them {evidence('small-steps')}.",
    )
    small_step_max: float = Field(
        2 / 20, gt=0, lt=0.5, description="s2, the largest small-step magnitude (twice the thesis's)."
    )
    reuse_beta: float = Field(
        2.2,
        description="beta of Eq. 5.4: p_s = 0.9 at equal losses, one step in ten renders (thesis 4.6: 0.99), "
        f"so minutes of training render enough patches {evidence('reuse-beta')}.",
    )
    reuse_ema: float = Field(0.9, ge=0, lt=1, description="Decay of the reuse losses' moving averages.")
    reuse_draw: Literal["loss", "uniform"] = Field(
        "loss",
        description="Reused patches drawn in proportion to their last loss (the thesis's rule), or "
        f"uniformly {evidence('reuse-draw')}.",
    )
    target_space: Literal["log1p", "display"] = Field(
        "display",
        description="The chains' loss f on the sRGB images shown or on log1p radiance (the training loss's); "
        f"display made the chains beat uniform on every scene measured {evidence('target-space')}.",
    )
    bootstrap: int = Field(20, ge=1, description="Generation steps before any reuse (App. A.7).")
    store_capacity: int = Field(4096, ge=2, description="Patches kept for reuse.")
    loss_l1_weight: float = Field(
        2.0, ge=0, description="w_1 of the loss w_1 |log1p L - log1p L_ref| + w_s (1 - SSIM)."
    )
    loss_ssim_weight: float = Field(
        1.0,
        ge=0,
        description="w_s, the weight of 1 - SSIM; needs patches larger than SSIM's window "
        f"{evidence('ssim-small-patches')}.",
    )
    torch_threads: int = Field(
        1,
        ge=1,
        le=256,
        description="torch threads while the model trains; more only busy-wait on a small network "
        f"{evidence('torch-threads')}.",
    )
    evaluation_configurations: int = Field(
        8, ge=1, le=64, description="Fixed configurations (seeded by the job) the report measures."
    )
    preview_size: int = Field(64, ge=8, le=2048, description="Side of the report's frames, pixels.")
    train: TrainConfig = Field(
        TrainConfig(
            steps=2000,
            schedule=Schedule(lr=5e-4, kind="cosine", final_lr_fraction=0.05),
            betas=(0.9, 0.999),
            eps=1e-8,
            grad_clip_norm=1.0,
            checkpoint_every=250,
            progress_every=20,
        ),
        description="The training loop: a larger rate than the thesis's 1e-4, decayed to the end, since "
        f"minutes of CPU training take thousands of steps, not 10^5 {evidence('learning-rate')}.",
    )

    @model_validator(mode="after")
    def _sizes_fit(self) -> ExploreConfig:
        if self.small_step_min > self.small_step_max:
            raise ValueError("small_step_min: must not exceed small_step_max")
        if self.resolution_start < self.patch:
            raise ValueError(
                f"resolution_start: {self.resolution_start} is smaller than a patch ({self.patch})"
            )
        if self.store_capacity < 2 * self.chains:
            raise ValueError(f"store_capacity: keep at least two patches per chain ({2 * self.chains})")
        if self.uniform_baseline and self.exploration == UNIFORM:
            raise ValueError("uniform_baseline: the run itself is the uniform baseline")
        if self.resolution_max < self.resolution_start:
            raise ValueError("resolution_max: must be at least resolution_start")
        return self

    @property
    def schedules_resolution(self) -> bool:
        """Whether R grows: `resolution_schedule`, by default for active exploration only (the thesis's
        uniform baseline has no schedule, Table 5.3)."""
        if self.resolution_schedule is None:
            return self.exploration != UNIFORM
        return self.resolution_schedule

    def resolution(self, iteration: int) -> int:
        """R at an iteration: grows by `resolution_step` every `resolution_every`, up to the maximum, or
        stays at the start without a schedule."""
        if not self.schedules_resolution:
            return self.resolution_start
        grown = self.resolution_start + self.resolution_step * (iteration // self.resolution_every)
        return min(grown, self.resolution_max)


PRESETS = load_presets(ExploreConfig, Path(__file__).with_name("presets"))
