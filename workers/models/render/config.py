"""The `render` kind's config and presets (`presets/*.yaml`): a reference path-traced image, sized for CI,
a 2-core CPU or GPUs."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, model_validator

from workers.render.render import RenderSettings
from workers.runtime.kind_config import KindConfig
from workers.runtime.presets import load_presets

# Refused before planning (a plan of a 16384^2 image at 2^20 spp took seconds to enumerate): the film of
# 8192^2 pixels with its AOVs is about 3.5 GB of float32; 2^36 samples is 16 times the `paper` preset.
MAX_PIXELS = 1 << 26
MAX_SAMPLES = 1 << 36


class RenderConfig(KindConfig):
    """What to render; the seed is not here because it belongs to the job (it is part of its identity)."""

    spp: int = Field(256, ge=1, le=1 << 20, description="Samples per pixel.")
    width: int = Field(256, ge=1, le=16384, description="Image width, pixels.")
    height: int = Field(256, ge=1, le=16384, description="Image height, pixels.")
    max_depth: int = Field(8, ge=1, le=1024, description="Most path segments a sample traces.")
    rr_depth: int = Field(5, ge=1, le=1024, description="Path depth from which Russian roulette ends paths.")
    tile_size: int = Field(64, ge=8, le=1024, description="Side of the square tiles samplers render, pixels.")
    aovs: bool = Field(True, description="Also write the G-buffers (position, normal, albedo, ...).")
    samplers: int = Field(
        2, ge=0, le=1024, description="Ray sampler actors rendering tiles; 0 renders inside the driver."
    )
    checkpoint_interval_s: float = Field(
        10.0,
        ge=0,
        le=86_400,
        description="Checkpoint after a pass once this many seconds have passed since the last one; 0: "
        "after every pass.",
    )

    @model_validator(mode="after")
    def _bounded(self) -> RenderConfig:
        pixels = self.width * self.height
        if pixels > MAX_PIXELS:
            raise ValueError(f"width x height is {pixels:,} pixels, over the limit of {MAX_PIXELS:,}")
        if pixels * self.spp > MAX_SAMPLES:
            raise ValueError(
                f"width x height x spp is {pixels * self.spp:,} samples, over the limit of {MAX_SAMPLES:,}"
            )
        return self

    def settings(self, seed: int) -> RenderSettings:
        """The renderer's settings: the same ones a direct render must use to give the same image."""
        return RenderSettings(
            spp=self.spp,
            width=self.width,
            height=self.height,
            max_depth=self.max_depth,
            rr_depth=self.rr_depth,
            seed=seed,
            tile_size=self.tile_size,
            aovs=self.aovs,
        )


PRESETS = load_presets(RenderConfig, Path(__file__).with_name("presets"))
