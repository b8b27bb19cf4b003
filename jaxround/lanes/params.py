"""LC2013's parameters: `jaxround.core.lane_change_params.LaneChangeParams`,
kept in the core so that `jaxround.core.params.EnvParams` carries them."""

from jaxround.core.lane_change_params import LaneChangeParams

__all__ = ["LaneChangeParams"]
