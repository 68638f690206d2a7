"""The `explore` kind's config and presets (thesis Ch. 5, App. A).

`paper` is the authors' README training command: 8 x 512 network, Adam 1e-4, 16 chains of 32^2 patches,
R from 128 to 600 by 4 every 2000 iterations, p_LS 0.3, small steps in [1/25, 1/20], beta 4.6, EMA 0.9,
a 100-generation bootstrap and a store of 1e5 patches. `default` and `quick` keep the method, shrink the
sizes for this 2-core CPU, take small steps twice as wide (`small_step_min`) and render a tenth of the
steps rather than a hundredth (`reuse_beta` 2.2).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from workers.nn.configs import HashGridConfig, MLPConfig
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import Schedule, TrainConfig

ACTIVE, UNIFORM = "active", "uniform"


class ExploreConfig(TrainedKindConfig):
    # Patches render in the driver by default: on this 2-core CPU a sampler actor competes with the
    # trainer for the same cores (set samplers >= 1 on a cluster).
    samplers: int = Field(0, ge=0, le=1024, description="Ray actors rendering the patches the chains ask for")
    # The network (Sec. 5.3.2, App. A.5): position alone into the first layer, then `depth` layers of
    # `width` that re-read the G-buffers and v. The thesis shows 128 wide is acceptable (Fig. A.6).
    mlp: MLPConfig = MLPConfig(width=128, depth=4, activation="leaky_relu")
    # A hash grid of the normalised position into the first layer (`network`; None: the thesis's network).
    # bench_explore's uniform run on cornell_variable (seed 3, antialiased frames): DSSIM of the averaged
    # weights 0.0508 / 0.0399 after 30 / 60 CPU s with it, 0.0632 / 0.0479 without (MAPE 0.179 / 0.207
    # at 60 s); table rate x10 instead of x30 was no better than none (pixel-centre frames, explore5)
    position_grid: HashGridConfig | None = HashGridConfig(
        levels=8, base_resolution=8, per_level_scale=1.5, log2_table_size=14
    )
    grid_lr_scale: float = Field(30.0, gt=0, description="the grid table's learning rate over the layers'")
    # The saved and measured network is an exponential average of the trained weights (`Explorer`)
    average_decay: float = Field(0.98, ge=0, lt=1, description="per-step decay of the weights' average")
    # bench_explore, 60 CPU s, seeds 3-5, averaged weights: active/uniform DSSIM 0.93 (cornell_variable)
    # and 1.18 (mirror_variable) at 0.86x uniform's steps once the targets were batched; 1.07 and 1.53 at
    # 0.65x with one backward pass per patch (explore5, explore6). With the rate decayed over the budget
    # as a job's is (explore24; 300 CPU s, averaged weights at the end, seeds 3 / 4 / 5): DSSIM 0.68 /
    # 0.76 / 0.80 on cornell_variable (MAPE 0.97 / 0.92 / 0.94), 1.22 / 1.15 / 1.07 on mirror_variable
    # (MAPE 0.93 / 0.90 / 0.90), 1.01 / 1.06 on the 8-dimension mirror_room_variable (MAPE 0.93 / 0.91).
    # At 900 CPU s on mirror_variable (explore25, seeds 3 / 4): 0.97 / 0.90 at the end (MAPE 0.97 / 0.85),
    # 1.18 / 1.09 over the second half: uniform's averaged DSSIM stops falling at ~0.03 from 450 s (seed
    # 3: 0.0306, 0.0329, 0.0275, 0.0299 every 150 s), as the thesis's uniform does (Table 5.3), while
    # active's keeps falling (0.0443, 0.0384, 0.0305, 0.0289). At 1800 CPU s (seed 4): 0.96 at the end
    # (0.0257 / 0.0267; MAPE 0.94), 1.09 over the second half: uniform stops at ~0.027 from 900 s, and
    # active reaches about that level rather than falling past it.
    # All of the above predate `mirror_bounces` = 1 and `target_space` = display. With them, at 900 CPU s
    # (explore27, seeds 3 / 4, averaged DSSIM at the end, active / uniform): mirror_variable 0.0200 /
    # 0.0225 (0.89) and 0.0163 / 0.0196 (0.83), 0.86 / 0.83 over the second half, MAPE 0.72 / 0.74:
    # uniform's DSSIM stays at 0.020-0.024 from 150 s on and its MAPE rises (seed 3: 0.100 to 0.117, the
    # glow around the light's reflection in the mirror, the error maps' brightest spot), while active's
    # keeps falling; seed 5 0.0171 / 0.0186 (0.92; 1.01 over the second half, MAPE 0.87).
    # cornell_variable 0.0117 / 0.0204 (0.58) and 0.0103 / 0.0173 (0.60), 0.61 / 0.66 over the second
    # half, MAPE 0.75 / 0.73
    exploration: Literal["active", "uniform"] = Field(
        ACTIVE, description="active: greedy chains on loss x Adam step (Sec. 5.4); uniform: the baseline"
    )
    # The job trains the uniform baseline as well, at equal wall-clock time, and its report gives both
    # runs' errors at the configurations (`baseline`): about twice the training time
    uniform_baseline: bool = Field(
        False, description="also train the uniform baseline at equal time and compare them in the report"
    )
    # The chains' state holds the patch position as well as v. On an underfit network the position is most
    # of what the target sees: 40 CPU s into a uniform run (16^2 patches of 64^2 views, a light sweeping to
    # a wall), the position explained 64% of the per-patch loss's variance and v 3%, and active runs
    # rendered the hard light positions at 0.97-1.14x the uniform rate; with whole-frame patches
    # (patch = R = 32) at 0.8-2.8x (explore4 notes)
    patch: int = Field(16, ge=4, le=128, description="side of a training patch, pixels")
    # Chains over v alone, so that f ranks configurations rather than patch positions, were measured as an
    # option and dropped (explore12; bench_explore 60 CPU s, seeds 3/4, one run under heavy load, averaged
    # weights, DSSIM over the second half against uniform, cornell / mirror). Paired: each generation draws
    # every chain a fresh position and renders the proposal and the current v there (the position's share
    # of the loss cancels; twice the renders): 1.08/0.99 and 1.05/1.25 (over uniform_schedule 1.17/1.10,
    # 1.04/1.14) at 0.74-0.78x uniform's steps; acceptance 0.49-0.51 and a state kept ~1 generation: at one
    # position f barely tells one v from another, so the chains walk nearly at random in v (at equal steps
    # 0.90/0.80 and 0.98/1.21). Unpaired (a fresh position per proposal, judged against the current v's
    # stored patch): 0.99/0.83 and 1.08/1.14, the chains parking again on the highlight's patch. Whole-view
    # patches (patch = R = 32, 2 chains, no schedule): 1.34/1.20 and 1.40/1.35.
    chains: int = Field(8, ge=1, le=256, description="Markov chains, one patch each per generation")
    # The schedule (Sec. 5.5.2), bench_explore 60 CPU s, seeds 3/4, averaged weights (explore7): active
    # without it is 28-32% worse on cornell_variable (0.041/0.040 vs 0.032/0.031) but 23-25% better on
    # mirror_variable (0.066/0.064 vs 0.085/0.085, where the chains park R = 128 patches on the light's
    # reflection). Uniform with the same schedule (bench harness only): cornell 0.028/0.029, i.e. better
    # than active; mirror 0.074/0.073 against 0.061/0.075 without. Kept: it is the method's, and it
    # measures better on one scene and worse on the other.
    # `resolution_schedule` makes uniform-with-schedule a configuration (bench arm `uniform_schedule`),
    # measured in the same run as the others (explore8; 60 CPU s, seeds 3/4, averaged weights, DSSIM /
    # MAPE): cornell active 0.0354/0.0379 (MAPE 0.200/0.200), uniform 0.0406/0.0397 (0.184/0.200),
    # uniform_schedule 0.0335/0.0326 (0.195/0.194); mirror active 0.0886/0.0898 (0.259/0.252), uniform
    # 0.0742/0.0774 (0.215/0.239), uniform_schedule 0.0780/0.0784 (0.206/0.183). So active/uniform is
    # 0.91 / 1.18 but active/uniform_schedule 1.11 / 1.14: at equal schedule the chains cost, not pay.
    # At 300 CPU s (stop 30; bench_explore, seed 3, one run, default active, EXPLORE_BENCH_RUN=
    # active,uniform) against the thesis's baseline, uniform without the schedule: averaged DSSIM at the
    # end cornell 0.0225 / 0.0260 (0.87), mirror 0.0531 / 0.0457 (1.16); over the second half 0.82 / 1.30,
    # MAPE 1.05 / 1.08 (steps 10095 / 12065 and 12140 / 15010). The same split as at 60 s
    resolution_schedule: bool | None = Field(
        None, description="grow R by the schedule; None: for active exploration only, as in Table 5.3"
    )
    resolution_start: int = Field(64, ge=4, le=8192, description="R at the start (Sec. 5.5.2)")
    resolution_max: int = Field(128, ge=4, le=8192)
    resolution_step: int = Field(4, ge=0, le=1024, description="pixels R grows by every `resolution_every`")
    resolution_every: int = Field(200, ge=1, description="iterations between resolution steps")
    # The hybrid of thesis Fig. 5.10: G-buffers traced through up to this many mirrors (near-smooth
    # conductors, `workers.render.gbuffer`), so the network learns the surfaces a mirror shows rather than
    # the reflection; 0 learns every path, as the thesis's main method does. Until explore26 it did not pay
    # on mirror_variable (uniform 0.0443, active 0.0683 against about 0.031 and 0.046 without; 300 CPU s,
    # seed 3, averaged DSSIM at the end): a reflection that escaped the open room left all-zero buffers,
    # which the network painted a flat grey. Now a camera ray that escapes shows the environment exactly
    # and a mirror whose reflection escapes stays in the buffers, so the network learns what its GGX tail
    # adds there (1-5 thousandths, the dark third of the view that dominated both arms' DSSIM). bench_explore
    # 300 CPU s, averaged DSSIM at the end, active / uniform, both arms with it (explore26): mirror_variable
    # seed 3 0.0195 / 0.0209 (0.94; 1.00 over the second half), seed 4 0.0280 / 0.0221 (1.27; 1.17);
    # cornell_variable, whose sphere is a mirror only below roughness 0.05, seed 4 0.0157 / 0.0204 (0.77;
    # 0.68-0.80 over seeds 3-5 without, explore24). On the mirror scene (seed 3) uniform's DSSIM falls by a
    # third (0.031 to 0.021) and active's by more than half (0.046 to 0.0195), so it is the default; with f
    # on log1p radiance whether the chains beat uniform there depended on the seed (see target_space)
    mirror_bounces: int = Field(1, ge=0, le=8, description="mirrors the G-buffers follow (0: none)")
    spp: int = Field(32, ge=1, le=1 << 16, description="path samples per pixel of a training patch")
    # A patch's G-buffers describe its pixels' centres, its area-sampled targets the pixels' areas: at an
    # edge (the light's, which moves with v) the target mixes surfaces the buffers do not show, an error
    # no network removes and whose gradient never fades, so f = loss x step stays high there (120 CPU s of
    # active on mirror_variable, explore14: 36% of the chains' states in the top-centre sixteenth of the
    # view, the light's). Centre targets, both arms (bench_explore 300 CPU s, 8192-spp references,
    # averaged DSSIM over the second half, seeds 3 / 4, explore14): active/uniform 0.70 / 0.77 on cornell
    # (chain age 1.6), 1.27 / 1.22 on mirror (3.3; 5.5 with area targets). But they cost uniform: in the
    # same run (seed 4) uniform with area targets was 0.83x uniform with centre targets on cornell (1.00x on
    # mirror), so active with centre targets is ~0.92x the strongest uniform there. Not the default: the
    # frames average the network over each pixel, and area targets measure better for the baseline.
    # Also measured and dropped: area targets with f judged only on the pixels whose 4-neighbours show the
    # same surface (position within 1/20 of the box, normals within ~25 degrees, same emission), same
    # bench, seed 4, one run: active/uniform 0.99 on cornell, 1.15 on mirror, chain age 3.0 there. The
    # chains stop parking on edges, yet active does not gain: the parking was not what it lacked
    target_pixel_samples: Literal["area", "centre"] = Field(
        "area", description="a patch's paths: over each pixel's area, or through its centre as its G-buffers"
    )
    max_depth: int = Field(5, ge=1, le=64, description="path segments of a training patch")
    # [code]: a rejected proposal is trained on beside the chain's current state, so batches hold
    # `chains` to 2 `chains` patches; without it they hold the chains' states after the decision only.
    # Dropping them did not pay in bench_explore (60 CPU s, seeds 3-4): active still got ~2300 steps to
    # uniform's ~3500 (the targets' passes are the overhead, not the batch), active/uniform DSSIM 1.10
    # and 1.62 against 1.07 and 1.53 with them (explore5). Re-measured with the batched targets
    # (cornell_variable, 60 CPU s, same run): 1.02x and 1.00x the steps (3210 vs 3150, 3405 vs 3405) at
    # 6% and 16% higher DSSIM of the averaged weights (0.0342 vs 0.0323, 0.0356 vs 0.0307; seeds 3, 4):
    # only ~11% of steps are fresh generations (the rest reuse `chains` stored patches), so the doubled
    # batches cost little and the rejected proposals are worth training on (explore7)
    train_rejected: bool = True
    # Against the chains parking on mirror_variable's highlight (mean chain age 5.7/3.1 generations there,
    # 2.2/1.1 on cornell), measured as options and dropped (explore8; bench_explore 60 CPU s, seeds 3/4,
    # averaged DSSIM over uniform_schedule's, cornell / mirror): Metropolis acceptance (Eq. 5.2; 85%
    # accepted, age 0.2) 1.13 / 1.10; a forced large step after 8 generations at a state 1.12 / 1.14;
    # the greedy rule 1.11 / 1.14. Why they park there: a parked chain's f decays by a median 24% over its
    # stay and stays 1.3x the proposals' median; 40% of the second half's states sit in the top centre
    # (uniform: 8%); those patches' loss against a converged render is as high (1.1-1.3) as against their
    # 16-spp target, i.e. real error the 64 x 3 network does not remove in the budget, while the other
    # parked patches' loss is mostly (62%) target noise. f from the loss above a noise floor (two
    # half-spp renders per patch, the floor half their mutual loss): 1.12 / 1.22 (separate run), dropped.
    # Also dropped (explore9; active arm alone, same budget and seeds, separate run under heavy load, over
    # explore8's uniform_schedule 0.0335/0.0326 and 0.0780/0.0784): p_LS 0.6: cornell 0.0427/0.0389
    # (1.27/1.19), mirror 0.0901/0.0764 (1.16/0.97), chain age 1.5/1.2 and 6.9/3.7; 16 chains (batches of
    # 16-32 patches, 0.5-0.7x the steps): cornell 0.0386/0.0415 (1.15/1.27), mirror 0.0820/0.0800 (1.05/1.02),
    # chain age 2.0/1.9 and 3.7/3.5; small steps halved (s1, s2 = 1/50, 1/40; separate run): cornell
    # 0.0513/0.0420 (1.53/1.29), mirror 0.0925/0.0938 (1.19/1.20), chain age 1.1/1.1 and 2.2/2.0.
    # None beats uniform_schedule on both scenes and seeds
    # A longer budget (explore10; bench_explore 300 CPU s, seed 3, one run, averaged weights, DSSIM / MAPE
    # at the end, steps): cornell active 0.0201/0.121 (11630), 16 chains 0.0217/0.127 (6735),
    # uniform_schedule 0.0187/0.109 (12915); mirror active 0.0547/0.154 (14720), 16 chains 0.0562/0.130
    # (8600), uniform_schedule 0.0611/0.116 (17410). The end points move by up to 20% between
    # measurements; over the second half (150-300 s) active's DSSIM is 1.08 / 1.13 times
    # uniform_schedule's (16 chains 1.14 / 1.14; MAPE 1.08 / 1.23): the gap is the one at 60 s, so the
    # chains do not start to pay once the easy parts are learned, at least not by 300 s. Small steps
    # doubled (s1, s2 = 2/25, 2/20; separate run, same seed and budget): cornell 0.0201/0.118 (11830),
    # mirror 0.0535/0.118 (15570); second half over uniform_schedule 1.06 / 1.07 (MAPE 1.04 / 1.09):
    # better than the default on both (most on mirror's MAPE, 1.23 -> 1.09) but not past uniform.
    # Quadrupled (4/25, 4/20; mirror only, separate run): 0.0521/0.128 (15470), second half 1.07 / 1.14,
    # chains parked longer (age 9.3, acceptance 0.21): the trend stops at doubling.
    # Nor is the deficit the bench network's capacity (explore11; bench_explore 300 CPU s, seed 3, one run
    # per size, small steps doubled in the active arm, active / uniform_schedule, cornell / mirror): at
    # 128 x 4 (81k layer weights, 4.4x the 64 x 3) the second-half DSSIM is 0.0232/0.0207 and
    # 0.0617/0.0585, ratio 1.12 / 1.06 (MAPE 1.05 / 1.03), at 0.78 / 0.84x uniform's steps (7360 vs 9465,
    # 9600 vs 11370); at 256 x 4 (294k) 0.0256/0.0254 and 0.0766/0.0708, ratio 1.01 / 1.08 (MAPE 1.11 /
    # 1.11), at 0.82 / 0.78x (4120 vs 5050, 4270 vs 5450). Against uniform_schedule at the same step count
    # (interpolated over its curve) 1.04 / 1.02 and 0.95 / 1.00. So across 18k-294k weights the ratio stays
    # within 1.0-1.12, nowhere near 0.75; the targets' per-patch gradients grow with the network, which
    # takes active from ~0.9x to ~0.8x uniform's steps. In 300 CPU s the larger networks do not lower the
    # error either: at the end, 128 x 4 is within the end points' noise of 64 x 3 (cornell 0.0217/0.0188
    # against 0.0201/0.0187, mirror 0.0512/0.0540 against 0.0535/0.0611), 256 x 4 is worse (0.0231/0.0231,
    # 0.0641/0.0647). So the bench keeps 64 x 3.
    # Against the baseline (uniform, no schedule) at 300 CPU s, averaged DSSIM over the second
    # half (explore13; bench_explore, one run each, cornell / mirror): seed 3 as is 0.85 / 1.38 (MAPE
    # 1.04 / 1.10), small steps doubled 0.85 / 1.15, doubled with R only to 96 0.87 / 1.23. Against
    # 8192-spp references (the 1024-spp ones carry DSSIM 0.017 of caustic noise on mirror), mirror seeds
    # 3 / 4: as is 1.41 / 1.06, small steps doubled 1.19 / 0.99. Targets at 64 spp instead of 16 (both
    # arms; ~0.6x the steps): 0.78 / 1.32 (at the end 0.74 / 1.38, MAPE 0.99 / 1.07): cleaner targets
    # help the chains on cornell, not on mirror, where they still park on the light's reflection
    # At 256 spp, the thesis's regime of few costly samples (explore15; same bench, seed 3, one run, on a
    # machine ~1.5x slower): renders are the budget (1736 / 1744 patches rendered on cornell), 2060 /
    # 2175 steps; averaged DSSIM at the end cornell 0.0332 / 0.0455 (0.73), mirror 0.0661 / 0.0576
    # (1.15); over the second half 0.84 / 1.13 (MAPE 1.09 / 0.93), and both arms' errors are above the
    # 16-spp runs' (cornell ~0.02): costlier, cleaner targets do not turn the ratio either
    # At 900 CPU s (explore16; default bench config, seed 3, one run): cornell active 0.0161 / uniform
    # 0.0219 at the end (0.74; MAPE 0.90), 0.73 over the second half (MAPE 0.95), at 0.89x uniform's
    # steps: the first run past 25% on cornell. Mirror 0.0441 / 0.0395 (1.12), 1.38 over the second half
    # (MAPE 1.07 / 1.02): the longer budget pays on cornell and not on mirror
    # At 900 CPU s, seed 4, the thesis's small steps (explore17): cornell 0.82 at the end, 0.88 over the
    # second half (MAPE 0.92 / 0.95); mirror 0.99 / 1.33 (MAPE 1.00 / 1.08)
    # With the rate decayed over the budget (explore24; 300 CPU s, seed 3, averaged DSSIM at the end over
    # uniform's, default 0.68 on cornell and 1.22 on mirror), dropped on mirror: reused patches drawn
    # uniformly in both arms 1.19, p_LS 0.5 1.11
    large_step_probability: float = Field(0.3, gt=0, le=1, description="p_LS of Eq. 5.1")
    # Small steps twice the thesis's 1/25-1/20 (`paper` keeps those): minutes of CPU training give the
    # chains tens of thousands of iterations, not hundreds of thousands, and wider steps leave a parked
    # state sooner. Better in every run that compared them (active over uniform, averaged DSSIM over the
    # second half, cornell / mirror; bench_explore): 300 CPU s, seed 3 1.08 -> 1.06 / 1.13 -> 1.07 against
    # uniform_schedule (explore10), 0.85 -> 0.85 / 1.38 -> 1.15 against uniform (explore13; mirror on
    # 8192-spp references, seeds 3 / 4: 1.41 -> 1.19, 1.06 -> 0.99); 900 CPU s, seed 4 0.88 -> 0.79 /
    # 1.33 -> 1.10, at the end 0.82 -> 0.76 / 0.99 -> 0.94 (explore17); seed 5, cornell only, these steps
    # (explore22): 0.73 at the end, 0.82 over the second half (MAPE 0.84 / 0.92); mirror, seed 5 (explore23):
    # 1.23 / 1.23 (MAPE 1.00 / 1.02). Four times: no further gain
    small_step_min: float = Field(2 / 25, gt=0, lt=0.5, description="s1: smallest small-step magnitude")
    small_step_max: float = Field(2 / 20, gt=0, lt=0.5, description="s2: largest small-step magnitude")
    # The paper's 4.6 (`paper`) keeps p_s near 0.99 (loss differences are ~0.1): 1 step in 100 renders. In
    # minutes of CPU training that leaves the chains tens of steps and the network a few hundred patches:
    # at 2.2 (p_s 0.9), bench_explore's 30 CPU s runs went from active / uniform DSSIM 1.28 to 1.10 on
    # cornell_variable and 1.27 to 1.01 on mirror_variable (one seed, 256-spp references), and a
    # `default` job with `uniform_baseline` (2000 steps, seeds 1 / 2, explore27) renders 1600-2000
    # patches instead of 300-360, at 1.3-1.6x the training CPU: its configurations' DSSIM falls from
    # 0.112 / 0.122 to 0.080 / 0.075 on mirror_variable (uniform 0.113 / 0.122 to 0.070 / 0.077) and
    # from 0.089 / 0.094 to 0.055 / 0.055 on cornell_variable (uniform 0.084 / 0.090 to 0.056 / 0.052).
    # At that length active and uniform stay at parity either way (0.97-1.15 at 2.2, 1.00-1.05 at 4.6)
    reuse_beta: float = Field(2.2, description="beta of Eq. 5.4: p_s = 0.9 at equal losses (paper 4.6: 0.99)")
    reuse_ema: float = Field(0.9, ge=0, lt=1, description="decay of the reuse losses' moving averages")
    # Reused patches drawn uniformly instead of by their last loss: a patch whose loss is mostly its target's
    # noise (mirror_variable's light reflected onto the room, where the chains park) is drawn no more often
    # than a clean one. bench_explore 300 CPU s, seed 3, averaged DSSIM over the second half (explore18-20;
    # uniform with uniform draws in a run of its own): active by loss / uniformly 0.0209 / 0.0213 on cornell,
    # 0.0566 / 0.0449 on mirror; uniform 0.0244 / 0.0268 and 0.0359 / 0.0312. Uniform draws help
    # both arms on mirror (0.79x, 0.87x) and cost uniform on cornell (1.10x); active over uniform with
    # the same draw: 0.86 / 1.58 by loss, 0.79 / 1.44 uniformly. Active with uniform draws and small steps
    # doubled (explore21): 0.0427 on mirror, 1.19x uniform by loss. The thesis's rule stays the default
    reuse_draw: Literal["loss", "uniform"] = Field(
        "loss", description="reused patches drawn in proportion to their last loss, or uniformly"
    )
    # f's loss on the sRGB images a preview shows (clamped to [0, 1], the space DSSIM is measured in)
    # instead of the training loss's log1p radiance: the light's edge and the light a mirror throws onto
    # the room, where the chains park, are large errors in log1p radiance and white once displayed.
    # bench_explore, decayed rate, 300 CPU s, averaged DSSIM over uniform's in the same run, at the end /
    # over the second half (explore24): mirror_variable seed 3 1.07 / 1.19 (log1p 1.22 / 1.15, separate
    # run), seed 4 0.97 / 1.02 (log1p 1.22 / 1.21, same run), MAPE 0.82 and 0.92; cornell_variable seed 3
    # 0.73 / 0.77 (log1p 0.68 / 0.70); mirror_room_variable seed 3 1.20 / 1.17 (log1p 1.01 / 1.02,
    # separate run). Better on mirror_variable, worse on the 8-dimension room: then an option.
    # With the mirror followed into the G-buffers (mirror_bounces, explore26; same bench, averaged DSSIM at
    # the end, active over uniform, display / log1p): mirror_variable seed 3 0.89 / 0.94 and seed 4 0.92 /
    # 1.27 (uniform from separate runs); cornell_variable seed 3 0.61 and seed 4 0.84 / 0.77 (same runs);
    # mirror_room_variable seed 3 0.99 / 1.02 (same run). Seed 5 with both defaults: mirror_variable 0.89
    # (1.02 over the second half), cornell_variable 0.77. The chains then beat uniform on every scene and
    # seed measured, so it is the default; in log1p radiance f no longer sees the glow a near-mirror adds
    # to the dark third of mirror_variable's view, where active's error lay on seed 4 (the error maps)
    # The training loss's SSIM term on the displayed images too (its L1 still on log1p; both arms, f the
    # training loss) was measured and dropped (explore25; 300 CPU s, seed 3, averaged DSSIM at the end,
    # active / uniform): mirror_variable 0.0387 / 0.0314 (1.23; log1p 0.0462 / 0.0308 in a run beside
    # CI), cornell_variable 0.0243 / 0.0272 (0.89; log1p 0.0164 / 0.0242, explore24). It costs both arms
    # on cornell, and its chains keep a state longer there (5.1 generations against ~2)
    target_space: Literal["log1p", "display"] = Field(
        "display", description="f's loss on the sRGB images shown or on log1p radiance (the training loss's)"
    )
    bootstrap: int = Field(20, ge=1, description="generation steps before any reuse (App. A.7)")
    store_capacity: int = Field(4096, ge=2, description="patches kept for reuse")
    loss_l1_weight: float = Field(
        2.0, ge=0, description="w_1 of w_1 |log1p L - log1p L_ref| + w_s (1 - SSIM)"
    )
    # SSIM needs patches larger than its window: on 8^2 patches it slowed learning (cornell_moving_light,
    # 1500 steps: FLIP 0.61 with it, 0.42 without), so `quick` leaves it out
    loss_ssim_weight: float = Field(1.0, ge=0, description="w_s, the weight of 1 - SSIM")
    # The network is small: one intra-op thread trained 600 steps of `quick` in 9 s on the loaded 2-core
    # CPU, two busy-waited (`workers.runtime.threads`); set more on an idle many-core machine
    torch_threads: int = Field(1, ge=1, le=256, description="torch threads while the model trains")
    # 8 fixed configurations (seeded by the job) measured against `reference_spp` at the view's size
    evaluation_configurations: int = Field(8, ge=1, le=64)
    preview_size: int = Field(64, ge=8, le=2048, description="side of the report's frames")
    # Adam 1e-4 in the paper over 10^5 iterations; minutes on a CPU need a larger step, decayed to the
    # end (in `quick`, cosine decay is what made the short run beat 1 spp reliably)
    train: TrainConfig = TrainConfig(
        steps=2000, schedule=Schedule(lr=5e-4, kind="cosine", final_lr_fraction=0.05), betas=(0.9, 0.999),
        eps=1e-8, grad_clip_norm=1.0, checkpoint_every=250, progress_every=20,
    )  # fmt: skip

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


PRESETS: dict[str, dict] = {
    "quick": {
        # cornell_moving_light, the report's 24^2 view: FLIP 0.42 / 0.43 against 0.46 / 0.52 for 1 spp
        # (seeds 5 / 6) at 1000 steps with cosine decay; a constant rate gave 0.46-0.75 over seeds and
        # settings, 100 steps 0.68. About a minute on the loaded 2-core CPU.
        "mlp": {"width": 32, "depth": 2},
        "position_grid": None,  # measured without
        "patch": 8,
        "chains": 4,
        "resolution_start": 16,
        "resolution_max": 24,
        "resolution_step": 4,
        "resolution_every": 100,
        "spp": 8,
        "max_depth": 3,
        "bootstrap": 50,
        "store_capacity": 512,
        "loss_ssim_weight": 0.0,
        "evaluation_configurations": 2,
        "preview_size": 24,
        "train": {
            "steps": 1000,
            "schedule": {"lr": 1e-2, "kind": "cosine", "final_lr_fraction": 0.02},
            "checkpoint_every": 500,
            "progress_every": 50,
        },
        "evaluation_spp": 2,
        "reference_spp": 128,
    },
    "default": {},
    "paper": {
        "mlp": {"width": 512, "depth": 8},
        "position_grid": None,
        "patch": 32,
        "chains": 16,
        "resolution_start": 128,
        "resolution_max": 600,
        "resolution_every": 2000,
        "spp": 400,
        "max_depth": 9,
        "small_step_min": 1 / 25,
        "small_step_max": 1 / 20,
        "reuse_beta": 4.6,
        "bootstrap": 100,
        "store_capacity": 100_000,
        "evaluation_configurations": 10,
        "preview_size": 512,
        "train": {
            "steps": 236_000,
            "schedule": {"lr": 1e-4, "kind": "constant"},
            "grad_clip_norm": None,
            "checkpoint_every": 2000,
        },
        "evaluation_spp": 64,
        "reference_spp": 1024,
        "num_gpus": 1,
    },
}
