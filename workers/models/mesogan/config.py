"""The `mesogan` kind's config and presets.

Lengths in the slab are in slab heights (the shell height on a mesh); plane positions in the same unit.
The thesis gives almost no sizes: `paper` uses the 128^2 ray-marched training and StyleGAN3-like widths
it names, `default` fits a 2-core CPU, `quick` is for tests (`presets/*.yaml`). Each field's description
says what it does, linking the measurement in docs/results/mesogan.md where one chose it.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from pydantic import Field, model_validator

from workers.nn.configs import MLPConfig
from workers.runtime.kind_config import TrainedKindConfig, results_link
from workers.runtime.presets import load_presets
from workers.runtime.training import OptimizerConfig, Schedule, TrainConfig
from workers.scene.format.spec import Appearance, Structure
from workers.scene.generators.mesoscale import MaterialKind

# The structure parameters training instances are drawn from: each uniform in its range.
STRUCTURE_RANGES = {"length": (0.4, 1.0), "density": (10.0, 80.0), "curliness": (0.0, 1.0)}
evidence = partial(results_link, "mesogan")


class MesoganConfig(TrainedKindConfig):
    """A GAN of mesoscale strands (fur, grass, carpet) on a shell over the scene's meshes: its training
    data, generator, decoder, discriminator and loss."""

    samplers: int = Field(
        0, ge=0, le=1024, description="Ray actors rendering training images; 0 renders them in the driver."
    )
    torch_threads: int | None = Field(
        1,
        ge=1,
        le=256,
        description="torch's intra-op threads while the job runs; one, since the GAN's small ops only "
        f"busy-wait on more {evidence('torch-threads')}.",
    )
    material: MaterialKind = Field("fur", description="The strand family the dataset is drawn from.")
    surfaces: list[str] = Field(["fur"], min_length=1, description="Scene materials the shell covers.")
    shell_height: float = Field(0.08, gt=0, description="World units of the shell on the scene's meshes.")
    structure: Structure = Field(
        Structure(), description="The strands' length, density and curliness the scene's shell shows."
    )
    appearance: Appearance = Field(Appearance(), description="The strands' colour the scene's shell shows.")
    image_size: int = Field(
        16, ge=8, le=256, description="Side of the path-traced training images (a power of two)."
    )
    training_spp: int = Field(16, ge=1, le=4096, description="Samples per pixel of a training image.")
    pool: int = Field(
        64, ge=2, description="Distinct rendered instances batches draw from (rendered once, cached)."
    )
    camera_distances: list[float] = Field(
        [2.5, 5.0], min_length=1, description="Training cameras' distances, slab heights (multi-scale)."
    )
    coarse_distances: list[float] = Field(
        [],
        description="Slab heights of the coarse views' cameras, whose wide pixels reach the coarse mip "
        f"levels (Sec. 6.2.7) while the view stays on the slab {evidence('coarse-views')}.",
    )
    coarse_block: int = Field(
        4, ge=1, description="Image pixels per side of a coarse view's pixel, shown as blocks."
    )
    coarse_lowest_elevation: float = Field(
        60.0, ge=5, le=85, description="Degrees above the slab of the lowest coarse camera (up to 85)."
    )
    fov: float = Field(30.0, gt=1, lt=120, description="Field of view of the training cameras, degrees.")
    light_irradiance: float = Field(3.0, gt=0, description="Irradiance of the training views' sun.")
    ambient: float = Field(0.3, ge=0, description="Radiance of the training views' uniform sky.")
    tile: float = Field(2.0, gt=0, description="Side of one tile of the rendered slab, slab heights.")
    tiles: int = Field(
        5, ge=1, le=9, description="Tiles per side of the rendered slab, so that views do not see past it."
    )
    latent_dims: int = Field(32, ge=1, description="Dimensions of the latent code z (Sec. 6.2.4).")
    w_dims: int = Field(32, ge=1, description="Dimensions of the style w the mapping network makes.")
    mapping: MLPConfig = Field(
        MLPConfig(width=64, depth=2, activation="leaky_relu"),
        description="The mapping network from z and the structure labels to w.",
    )
    plane_channels: int = Field(8, ge=1, description="Channels of the generated feature plane.")
    plane_resolution: int = Field(32, ge=8, description="Texels per side of the training window.")
    texel: float = Field(0.25, gt=0, description="Plane units (slab heights) per texel.")
    mip_levels: int = Field(3, ge=1, le=12, description="Mip levels of the feature plane.")
    fourier_features: int = Field(16, ge=1, description="Fourier features of the generator's input.")
    injected_features: int = Field(8, ge=1, description="Fourier features injected at each layer.")
    generator_layers: int = Field(2, ge=1, le=16, description="Modulated convolution layers (Sec. 6.2.5).")
    generator_width: int = Field(32, ge=4, description="Channels of the generator's layers.")
    input_band: float = Field(
        0.1, gt=0, le=1, description="Input frequencies up to this fraction of Nyquist."
    )
    top_band: float = Field(0.9, gt=0, le=1, description="The last layer's cutoff as a fraction of Nyquist.")
    inject: bool = Field(True, description="Random Fourier features injected at every layer (Sec. 6.2.5).")
    redraw_frequencies: bool = Field(True, description="Input frequencies re-drawn every step (Sec. 6.2.4).")
    mipmapping: bool = Field(
        True,
        description="Cone footprints select mip levels (Sec. 6.2.7); without them far views shimmer 1.14x "
        f"as much {evidence('mipmapping')}.",
    )
    height_frequencies: int = Field(
        4, ge=1, le=16, description="Frequencies encoding a sample's height in the slab for the decoder."
    )
    decoder: MLPConfig = Field(
        MLPConfig(width=32, depth=2, activation="leaky_relu"),
        description="The MLP decoding plane features and height into extinction and a hidden state "
        "(Sec. 6.2.6).",
    )
    radiance_head: MLPConfig = Field(
        MLPConfig(width=32, depth=1, activation="leaky_relu"),
        description="The MLP turning the hidden state, colour, light and view into radiance (Eq. 6.4).",
    )
    samples_per_ray: int = Field(8, ge=2, le=256, description="Ray-marching samples per ray in the slab.")
    ambient_directions: int = Field(
        2, ge=1, le=64, description="Hemisphere directions per sample for the ambient term A."
    )
    discriminator_width: int = Field(32, ge=4, description="Channels of the discriminator's layers.")
    r1_gamma: float = Field(1.0, ge=0, description="Weight of the R1 gradient penalty on real images.")
    mean_color_weight: float = Field(
        10.0, ge=0, description="Generator: weight of the L1 of fake and real block means."
    )
    moment_block: int = Field(4, ge=1, description="Pixels per side of the blocks whose means are matched.")
    structure_weight: float = Field(
        10.0,
        ge=0,
        description="Generator: weight of the L1 of fake and real views' coverage and mean first-hit "
        f"height; without it the GAN never learns the structure labels {evidence('structure-weight')}.",
    )
    batch_size: int = Field(8, ge=1, description="Training images per step.")
    train: TrainConfig = Field(
        TrainConfig(
            steps=2000,
            checkpoint_every=250,
            optimizers={
                "discriminator": OptimizerConfig(schedule=Schedule(lr=2e-3), betas=(0.0, 0.99), eps=1e-8),
                "generator": OptimizerConfig(schedule=Schedule(lr=2e-3), betas=(0.0, 0.99), eps=1e-8),
            },
        ),
        description="The training loop: one Adam each for the discriminator and the generator, StyleGAN's "
        f"2e-3 with betas (0, 0.99) {evidence('generator-rate')}.",
    )
    preview_size: int = Field(48, ge=8, le=2048, description="Side of the report's frames, pixels.")
    max_depth: int = Field(4, ge=2, le=64, description="Path segments of the report's renders.")
    evaluation_instances: int = Field(
        16, ge=2, description="Held-out renders per set for the report's SWD figure."
    )

    @model_validator(mode="after")
    def _sizes(self) -> MesoganConfig:
        if self.image_size & (self.image_size - 1):
            raise ValueError(f"image_size: must be a power of two, got {self.image_size}")
        if self.image_size % self.coarse_block:
            raise ValueError(f"coarse_block: {self.coarse_block} must divide image_size {self.image_size}")
        if self.plane_resolution >> (self.mip_levels - 1) < 1:
            raise ValueError(f"mip_levels: {self.mip_levels} levels need plane_resolution >= 2^(levels-1)")
        return self


PRESETS = load_presets(MesoganConfig, Path(__file__).with_name("presets"))
