"""The `render` kind's config and presets: a reference path-traced image, sized for CI, this CPU or GPUs."""

from __future__ import annotations

from pydantic import Field

from workers.render.render import RenderSettings
from workers.runtime.kind_config import KindConfig


class RenderConfig(KindConfig):
    """What to render; the seed is not here because it belongs to the job (it is part of its identity)."""

    spp: int = Field(256, ge=1, le=1 << 20)
    width: int = Field(256, ge=1, le=16384)
    height: int = Field(256, ge=1, le=16384)
    max_depth: int = Field(8, ge=1, le=1024)
    rr_depth: int = Field(5, ge=1, le=1024)
    tile_size: int = Field(64, ge=8, le=1024)
    aovs: bool = Field(True, description="also write the G-buffers (position, normal, albedo, ...)")
    samplers: int = Field(2, ge=0, le=1024, description="Ray sampler actors; 0 renders inside the driver")
    # Checkpoint after a pass once this many seconds have passed since the last one; 0: after every pass.
    checkpoint_interval_s: float = Field(10.0, ge=0, le=86_400)

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


PRESETS: dict[str, dict] = {
    "quick": {"width": 64, "height": 64, "spp": 16, "tile_size": 32, "checkpoint_interval_s": 0},
    "default": {"width": 256, "height": 256, "spp": 256},
    "paper": {"width": 1024, "height": 1024, "spp": 4096, "samplers": 8, "checkpoint_interval_s": 60},
}
