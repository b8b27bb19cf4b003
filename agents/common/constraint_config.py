"""The conflict constraint of constrained PPO: its settings, from YAML.

    conflict_constraint:      # in a PPO config; absent or null: a fixed price
      limit: []               # conflicts per 1,000 vehicles, one per penetration
                              # (or one for all); []: the AVs' own vType,
                              # uncontrolled, measured when training starts
      price_lr: 0.05          # log-price step per update at full excess: the
                              # price moves by at most 5% an update
      price_min: 1.0          # the price stays within [price_min, price_max],
      price_max: 5000.0       # vehicle-seconds per conflict
      measure_episodes: 2     # episodes of the batch that measure the vType's rate
                              # (2 are noisy, +-30%; more made ppo_milan no
                              # safer at 50% AVs: docs/safety.md)
      smoothing: 0.9          # decay of the running count the rate is taken from

The price of a conflict (`agent.conflict_weight` of the system reward) then
starts at the config's `conflict_weight` and follows the constraint, one
price per penetration, as the Lagrange multiplier of constrained PPO
(`agents.ppo.constraint`).
"""

from __future__ import annotations

from dataclasses import dataclass

from jaxround.scenario.loader import ConfigError


@dataclass(frozen=True)
class ConflictConstraintConfig:
    """Settings of the Lagrangian conflict price (see the module docstring)."""

    limit: tuple[float, ...] = ()  # per 1,000 vehicles, per penetration; (): vType's
    price_lr: float = 0.05  # log-price step per update at full relative excess
    price_min: float = 1.0  # lower bound of the price, vehicle-seconds
    price_max: float = 5000.0  # upper bound of the price, vehicle-seconds
    measure_episodes: int = 2  # batch episodes measuring the vType's own rate
    smoothing: float = 0.9  # decay of the running conflict and arrival counts

    def validate(self, n_penetrations: int, where: str = "conflict_constraint") -> None:
        """Raise `ConfigError` naming the first bad field."""
        if len(self.limit) not in (0, 1, n_penetrations):
            raise ConfigError(
                f"{where}.limit: {len(self.limit)} numbers, expected none (the "
                f"vType's own rate), one, or one per penetration ({n_penetrations})"
            )
        for i, x in enumerate(self.limit):
            if x < 0:
                raise ConfigError(f"{where}.limit[{i}]: {x}, expected >= 0")
        if self.price_lr <= 0:
            raise ConfigError(f"{where}.price_lr: {self.price_lr}, expected > 0")
        if not 0 < self.price_min <= self.price_max:
            raise ConfigError(
                f"{where}.price_min, price_max: {self.price_min}, "
                f"{self.price_max}, expected 0 < price_min <= price_max"
            )
        if self.measure_episodes < 1:
            raise ConfigError(
                f"{where}.measure_episodes: {self.measure_episodes}, expected >= 1"
            )
        if not 0 <= self.smoothing < 1:
            raise ConfigError(
                f"{where}.smoothing: {self.smoothing}, expected in [0, 1)"
            )

    def limits(self, n_penetrations: int) -> tuple[float, ...]:
        """One limit per penetration (empty: to be measured)."""
        if len(self.limit) == 1:
            return self.limit * n_penetrations
        return self.limit


__all__ = ["ConflictConstraintConfig"]
