"""Surrogate safety settings, shared by both simulators.

SUMO measures near-conflicts with its SSM device (``MSDevice_SSM``,
``src/microsim/devices/MSDevice_SSM.cpp``): for every pair of vehicles
within ``range_m`` of each other it follows an *encounter*, traces the
time to collision (TTC) and the deceleration to avoid a crash (DRAC), and
writes a ``<conflict>`` for an encounter whose smallest TTC is at most
``ttc_threshold_s`` or whose largest DRAC is at least ``drac_threshold_mps2``.
`SafetyConfig.sumo_options` turns these numbers into the device's options; the JAX
environment counts the same conflicts (`jaxround.core.surrogate_safety`).

``min_av_tau_s`` is the smallest time gap an AV may be given, by an action
or a searched setting: 0.8 s is the smallest time gap ISO 15622 lets an
adaptive cruise control offer.
"""

from __future__ import annotations

from dataclasses import dataclass

from jaxround.scenario.loader import ConfigError, check_non_negative, check_positive

#: ISO 15622's smallest time gap an adaptive cruise control may offer, s.
ISO_15622_MIN_TIME_GAP_S = 0.8


@dataclass(frozen=True)
class SafetyConfig:
    """How near-conflicts are measured, and the AVs' time-gap floor."""

    ttc_threshold_s: float = 1.5  # a conflict: TTC at or below this, s
    drac_threshold_mps2: float = 3.0  # ... or DRAC at or above this, m/s^2
    range_m: float = 50.0  # SUMO's --device.ssm.range: pairs within this, m
    extra_time_s: float = 5.0  # SUMO's --device.ssm.extratime, s
    # the smallest tau (time gap) any AV setting or action may give, s
    min_av_tau_s: float = ISO_15622_MIN_TIME_GAP_S

    def validate(self, where: str) -> None:
        check_positive(self.ttc_threshold_s, f"{where}.ttc_threshold_s")
        check_positive(self.drac_threshold_mps2, f"{where}.drac_threshold_mps2")
        check_positive(self.range_m, f"{where}.range_m")
        check_non_negative(self.extra_time_s, f"{where}.extra_time_s")
        check_non_negative(self.min_av_tau_s, f"{where}.min_av_tau_s")
        if self.min_av_tau_s > 5.0:
            raise ConfigError(
                f"{where}.min_av_tau_s: {self.min_av_tau_s}, expected at most 5 s"
            )

    def sumo_options(self, output_file: str) -> list[str]:
        """The SSM device on every vehicle, with these thresholds, writing to
        `output_file` (SUMO's ``--device.ssm.*`` options)."""
        return [
            "--device.ssm.probability", "1",
            "--device.ssm.measures", "TTC DRAC",
            "--device.ssm.thresholds",
            f"{self.ttc_threshold_s:g} {self.drac_threshold_mps2:g}",
            "--device.ssm.range", f"{self.range_m:g}",
            "--device.ssm.extratime", f"{self.extra_time_s:g}",
            "--device.ssm.file", output_file,
        ]  # fmt: skip
