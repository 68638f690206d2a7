"""What a `prt` job captures: the lightings training draws and the camera trajectories its views lie on,
and which of each are held out (parts of `PrtConfig`)."""

from __future__ import annotations

from functools import partial

from pydantic import Field, model_validator

from workers.runtime.kind_config import results_link
from workers.scene.format.strict import StrictModel

evidence = partial(results_link, "prt")


class LightingConfig(StrictModel):
    """Where training lightings come from (a fresh one every step, Sec. 5) and which are held out.

    Each step draws a procedural `sky` (random sun) or `studio` (random softboxes) or one of the
    `train_hdris`, turned about the vertical by a random angle. Held-out lightings are the `test_hdris`
    and procedural maps from a seed stream training never draws from."""

    train_hdris: list[str] = Field(
        ["courtyard", "city", "interior", "studio", "sunrise", "night"],
        description="Built-in HDRIs training draws from; must not overlap `test_hdris`.",
    )
    test_hdris: list[str] = Field(
        ["sunset", "forest"], description="Built-in HDRIs held out of training and used only to measure."
    )
    procedural_fraction: float = Field(
        0.5,
        ge=0,
        le=1,
        description="Share of training steps lit by a procedural sky or studio rather than an HDRI; 0.75 "
        f"was no better {evidence('procedural-fraction')}.",
    )
    test_procedural: int = Field(
        2, ge=0, le=64, description="Held-out procedural maps (one sky, one studio, ...)."
    )
    map_width: int = Field(
        128, ge=8, le=4096, description="Width of the lat-long maps lightings are generated and filtered at."
    )

    @model_validator(mode="after")
    def _disjoint(self) -> LightingConfig:
        shared = set(self.train_hdris) & set(self.test_hdris)
        if shared:
            raise ValueError(f"held-out HDRIs {sorted(shared)} are also training HDRIs")
        if not self.train_hdris and self.procedural_fraction < 1:
            raise ValueError("no training HDRIs: set procedural_fraction to 1")
        return self


class CamerasConfig(StrictModel):
    """Camera trajectories around the scene camera's target (Sec. 6: spheres/helices around the scene).

    Training views lie on a helix at the scene camera's distance; "near" test views are held-out points
    on the same helix, "far" test views lie on another one (`far_scale` times the distance, `far_lift`
    degrees higher); `train_band` spreads the training views over the band between the two helices."""

    train_views: int = Field(
        96,
        ge=1,
        le=4096,
        description="Training views whose transport is traced; at equal rows, 24 to 96 views scored alike "
        f"{evidence('views')}.",
    )
    near_views: int = Field(2, ge=0, le=64, description="Held-out views on the training helix.")
    far_views: int = Field(2, ge=0, le=64, description="Held-out views on the far helix.")
    elevation_range: tuple[float, float] = Field(
        (12.0, 40.0), description="Degrees above the target the helix climbs from and to."
    )
    azimuth_range: float = Field(90.0, gt=0, le=360, description="Degrees of arc the helix sweeps.")
    far_scale: float = Field(
        0.8, gt=0.1, le=4, description="The far helix's distance as a multiple of the scene camera's."
    )
    far_lift: float = Field(10.0, ge=-80, le=80, description="Degrees the far helix lies above the other.")
    train_band: float = Field(
        1.0,
        ge=0,
        le=1,
        description="How far towards the far helix training views spread (0: one helix); 1 took far views "
        f"to within 0.4 dB of near ones {evidence('train-band')}.",
    )
