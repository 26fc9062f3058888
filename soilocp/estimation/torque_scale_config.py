"""Settings of the online torque scale (:mod:`soilocp.estimation.torque_scale` says what it learns and
how): pydantic only, no numpy (:mod:`soilocp.estimation.config`)."""

from __future__ import annotations

from typing import Optional

from pydantic import BaseModel, ConfigDict, Field


class TorqueScaleConfig(BaseModel):
    """Settings of the online torque scale (module doc)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    enabled: bool = Field(True, description="Learn the torque scale online (False: k = 1 +- soil.gross_scale_sigma always)")
    window: float = Field(1.0, gt=0, description="s: the force balance is taken over window means")
    min_speed: float = Field(0.2, gt=0, description="m/s: slower windows are left out (static friction, stall)")
    max_yaw_rate: float = Field(0.1, gt=0, description="rad/s: a skid turn spends torque on scrubbing the wheels sideways")
    max_gap: float = Field(0.25, gt=0, description="s: a larger step between stamps restarts the window")
    min_accel: float = Field(0.35, gt=0, description="m/s^2: the window's mean acceleration that informs k")
    max_slip: float = Field(
        0.15, gt=0, description="|slip| (eq. 1, from the readings) above which a window informs nothing: motion "
        "resistance grows with slip (eq. 4), and under a slip sweep its swings follow the torque's (the robust-mix "
        "traction test read k 0.84 for 1.00 with them)")
    scale_walk: float = Field(0.002, ge=0, description="Random walk of k, 1/sqrt(s)")
    resistance_walk: float = Field(2.0, ge=0, description="Random walk of F_MR, N/sqrt(s)")
    resistance_sigma: float = Field(60.0, gt=0, description="Prior 1-sigma of F_MR, N (prior mean 0)")
    force_sigma: float = Field(
        1.0, gt=0, description="1-sigma of a window's balance, N: its noise once F_MR's changes are the random walk's "
        "and resistance_jump's (with the true F_MR the simulated drives' windows leave 0.2-0.8 N rms, 1.7 N at most; "
        "3 N, which had to cover soil changes too, before the jumps)")
    resistance_jump: float = Field(
        3.0, ge=0, description="A window whose innovation is beyond this many of its own sigmas is a jump of F_MR (the "
        "soil under the wheels changed, a draft was hooked on), not a change of k: F_MR's variance returns to "
        "resistance_sigma and the window informs F_MR alone (0: never).  A soil change moves F_MR by 10-25 N at the "
        "swing's small slips, which at 0.5 m/s^2 on 60 kg the random walk read as a 5-8 % change of k")
    model_resistance: bool = Field(
        False, description="Subtract eq. 4's motion resistance at the soil stage's K and slips from the balance "
        "(modelled_resistance), leaving b the unmodelled rest; False: b is the whole F_MR, a random walk.  Off by "
        "default: measured worse on the accelerate/brake drives (its slips and K are estimates).  The K is fed "
        "back in the offline and batched paths only: the live observer service runs before the soil service and "
        "models the resistance at the median reference soil and the readings' slips")
    prior_sigma: Optional[float] = Field(
        0.10, gt=0, description="Prior 1-sigma of k (motor constant x 1 / mass) for the online state (None: "
        "soil.gross_scale_sigma, the torque constant's alone): a payload the vehicle file does not know is a scale "
        "error too (+25 %: k 0.80).  K's band combines the windows' information with soil.gross_scale_sigma "
        "(TorqueScaleBank.band_sigma)")
