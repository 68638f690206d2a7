"""The `prt` kind's config (Raghavan et al. 2023, "Neural Free-Viewpoint Relighting for Glossy Indirect
Illumination", Sec. 4 and Table 2) and its presets (`presets/*.yaml`).

The defaults are sizes measured on a 2-core CPU; `paper` is the paper's network. Each field's description
says why its default, linking the measurement in docs/results/prt.md.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from workers.models.prt.capture import CamerasConfig, LightingConfig
from workers.nn.configs import HashGridConfig, MLPConfig, SphericalHarmonicsConfig
from workers.runtime.kind_config import TrainedKindConfig, results_link
from workers.runtime.presets import load_presets
from workers.runtime.training import Schedule, TrainConfig

FRAME_SPP = (4, 8, 16, 32, 64)
FLOPS_PER_RAY = 16_000.0
evidence = partial(results_link, "prt")


class PrtConfig(TrainedKindConfig):
    """Neural-wavelet PRT's knobs: the lighting's cube and wavelets, the traced rows that are its ground
    truth, the network, its training, and the frame the artifact renders."""

    samplers: int = Field(
        0,
        ge=0,
        le=1024,
        description="Ray actors generating training batches; 0 makes them in the driver, which holds the "
        f"traced rows once {evidence('samplers')}.",
    )
    cube_size: int = Field(
        8, ge=2, le=128, description="R: texels per cube-face side of the lighting (a power of two)."
    )
    wavelets: int = Field(
        64,
        ge=1,
        description="K: run-time wavelets, selected per frame; truncating to 64 cost nothing measurable "
        f"{evidence('wavelets')}.",
    )
    selection: Literal["area", "magnitude"] = Field(
        "area", description="How a frame ranks wavelets: by area-weighted or by plain coefficient magnitude."
    )
    train_top_wavelets: int = Field(
        48, ge=0, description="Per step: wavelets with the largest |L_k| (paper 150)."
    )
    train_uniform_wavelets: int = Field(
        48, ge=0, description="Per step: wavelets drawn uniformly among the rest (paper 150)."
    )
    pixels_per_step: int = Field(
        128,
        ge=4,
        description="Pixels per step, an equal share from each pixel map (paper 2048); twice as many gained "
        f"about a run's spread for twice the cost {evidence('pixels-per-step')}.",
    )
    lightings_per_step: int = Field(
        8,
        ge=1,
        description="Lightings per step, each with its own wavelets and share of pixels (paper 1); 8 beat 1 "
        f"by 1.7-2.6 dB, more no longer helped {evidence('lightings-per-step')}.",
    )
    lighting_pool: int = Field(
        1024,
        ge=0,
        le=1 << 16,
        description="Training lightings built once and drawn from (0: a fresh one every draw); pooled ones "
        f"cost a third less training time {evidence('lightings-per-step')}.",
    )
    grid: HashGridConfig = Field(
        HashGridConfig(
            levels=8, features_per_level=8, log2_table_size=14, base_resolution=8, per_level_scale=1.5
        ),
        description="The hash grid S(x) of positions; 8 features a level make the paper's M = 64, which "
        f"underfits less than 16 {evidence('grid')}.",
    )
    directions: SphericalHarmonicsConfig = Field(
        SphericalHarmonicsConfig(degree=4),
        description=f"Encoding of the view direction; degree 2 or 6 scored alike {evidence('directions')}.",
    )
    mlp: MLPConfig = Field(
        MLPConfig(width=64, depth=2, activation="relu"),
        description="f, the network of the grid and direction features; 128 wide (the paper's) gains 0.55 "
        f"dB for a 2.2x slower frame, 32 wide makes the fastest frame {evidence('mlp')}.",
    )
    torch_threads: int | None = Field(
        1,
        ge=1,
        le=256,
        description="torch's intra-op threads while the job runs; one, since more only busy-wait on these "
        f"small networks {evidence('torch-threads')}.",
    )
    transport_weight: float = Field(
        1.0,
        ge=0,
        description="Weight of per-wavelet transport supervision from the rows (0: the paper's loss); 1 "
        f"stopped the network under-predicting held-out indirect light {evidence('transport-weight')}.",
    )
    mu: float = Field(
        10.0,
        gt=0,
        description=f"mu of the loss's mu-law tonemap (Sec. 5); a linear loss scored alike {evidence('mu')}.",
    )
    image_size: int = Field(48, ge=4, le=4096, description="Side of training and test views, pixels.")
    rows_per_view: int = Field(
        1536,
        ge=1,
        description="Pixels per training view whose transport is stored (at most all it sees); about +1 dB "
        f"per 4x rows, 4.5 kB each {evidence('rows-per-view')}.",
    )
    row_spp: int = Field(
        256,
        ge=1,
        le=1 << 16,
        description="Paths per stored pixel; 256 gained 0.3-0.6 dB over 128 for a sixth more job time, 512 "
        f"nothing more {evidence('row-spp')}.",
    )
    row_neighbours: int = Field(
        128,
        ge=1,
        le=256,
        description="Training targets: the mean of at most this many nearest rows on the row's object, as "
        "many as leave-one-out chooses per object (1: the rows themselves); cleaner targets gain ~1 dB "
        f"{evidence('row-neighbours')}.",
    )
    test_spp: int = Field(
        256, ge=1, le=1 << 16, description="Paths per pixel of the held-out truth, per lighting."
    )
    max_depth: int = Field(8, ge=3, le=64, description="Path segments of the traced rows and truth.")
    probe_spp: int = Field(
        4, ge=1, le=256, description="Paths per pixel of the plan's probe of the scene's indirect light."
    )
    lighting: LightingConfig = Field(
        LightingConfig(), description="Where training lightings come from and which are held out."
    )
    cameras: CamerasConfig = Field(CamerasConfig(), description="Training and held-out camera trajectories.")
    train: TrainConfig = Field(
        TrainConfig(
            steps=16000,
            schedule=Schedule(lr=0.003, kind="cosine", final_lr_fraction=0.05),
            fused=True,
            checkpoint_every=500,
            progress_every=20,
        ),
        description=f"The training loop: 16000 steps still gain over 8000 {evidence('steps')}, at lr 0.003 "
        f"{evidence('learning-rate')}.",
    )
    held_out_spp: int = Field(
        64,
        ge=1,
        le=65536,
        description="The held-out figures' direct light: spp, denoised, the network at every pixel, so that "
        f"they measure the network {evidence('direct-spp')}.",
    )
    evaluation_spp: int | None = Field(
        None,
        ge=1,
        le=65536,
        description="The artifact frame's direct-light spp; None: the job tries 4 to 64 on the report's view "
        "and takes the one that beats path tracing by most at equal counted cost, since each scene's best "
        f"differs {evidence('evaluation-spp')}.",
    )
    flops_per_ray: float = Field(
        FLOPS_PER_RAY,
        gt=0,
        description="Choosing the artifact's frame by counted cost: the network FLOPs that cost as much as "
        f"one traced ray, fixed so the choice is the same on any machine {evidence('flops-per-ray')}.",
    )
    denoise_direct: bool = Field(
        False,
        description="The artifact's frame: filter its direct light (G-buffer-guided à-trous); it pays below "
        f"32 spp {evidence('frame-curve')}.",
    )
    checkerboard: bool = Field(
        True,
        description="The artifact's frame: the network shades half the pixels, the rest are filled from "
        f"neighbours, for a 17% faster frame {evidence('checkerboard')}.",
    )
    bfloat16_products: bool = Field(
        True,
        description="Relighting: f's first and hidden products in bfloat16 where the device has it natively, "
        f"1.4-1.6x faster at the same error {evidence('bfloat16')}.",
    )
    reference_spp: int = Field(
        256,
        ge=2,
        le=1 << 20,
        description="Paths per pixel of the converged image the report is measured against.",
    )

    @model_validator(mode="after")
    def _reference_converges_further(self) -> PrtConfig:
        """As every trained kind's, once the frame's spp is fixed (None: the job keeps to counts under the
        reference's)."""
        if self.evaluation_spp is None:
            return self
        return super()._reference_converges_further()

    @model_validator(mode="after")
    def _sizes(self) -> PrtConfig:
        r = self.cube_size
        if r & (r - 1):
            raise ValueError(f"cube_size must be a power of two (Haar), got {r}")
        total = 6 * r * r
        if self.wavelets > total:
            raise ValueError(
                f"wavelets: K = {self.wavelets} exceeds the {total} wavelets of a 6 x {r}^2 cube"
            )
        if self.train_top_wavelets + self.train_uniform_wavelets == 0:
            raise ValueError("train_top_wavelets + train_uniform_wavelets must be positive")
        return self

    @property
    def frame_spp_choices(self) -> tuple[int, ...]:
        """The direct-light counts a job times for its frame (`frame_spp`): the config's, or 4 to 64 under
        the reference's."""
        if self.evaluation_spp is not None:
            return (self.evaluation_spp,)
        return tuple(spp for spp in FRAME_SPP if spp < self.reference_spp)

    @property
    def n_wavelets(self) -> int:
        return 6 * self.cube_size**2


PRESETS = load_presets(PrtConfig, Path(__file__).with_name("presets"))
