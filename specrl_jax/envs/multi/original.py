"""The original multi-agent observation layout: one dict per agent, keys suffixed `_<i>`.

Per agent i, in the original's order: the robot sensors (`accelerometer_i`, `velocimeter_i`,
`gyro_i`, `magnetometer_i`, then any other robot sensors alphabetically), the zone LiDAR of each
colour in placement order (`green_zones_lidar_i`, `yellow_...`, `blue_...`, `magenta_...`), the
LiDAR of the other agents (`gremlins_lidar_i`) and the wall sensor (`wall_sensor_i`): 96 values
for a Point.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

IMU_ORDER = ("accelerometer", "velocimeter", "gyro", "magnetometer")


class OriginalLayout:
    """Maps a stacked observation (`ap [N, P, 16]`, `ego [N, E + 4]`, `others [N, 1, 16]`,
    numpy or JAX, one world) to `{"agent_i": {key_i: float32[...]}}` and describes its space."""

    def __init__(self, env: Any):
        robot, config = env.world.robot, env.config
        offsets, start = {}, 0
        for name, size in robot.ego_keys:
            offsets[name] = (start, start + size)
            start += size
        sensors = [k for k in IMU_ORDER if k in offsets] + sorted(set(offsets) - set(IMU_ORDER))
        bins = config.zone_config.num_bins
        # (key stem, source obs key, index into that agent's row, size, bounded in [0, 1])
        self.entries: list[tuple[str, str, Any, int, bool]] = [
            (name, "ego", slice(*offsets[name]), offsets[name][1] - offsets[name][0], False)
            for name in sensors
        ]
        self.entries += [
            (f"{c}_zones_lidar", "ap", env.colour_propositions.index(c), bins, True)
            for c in config.colors
        ]
        self.entries += [
            ("gremlins_lidar", "others", 0, bins, True),
            ("wall_sensor", "ego", slice(start, start + 4), 4, True),
        ]
        self.agents = env.agents

    def space(self) -> gymnasium.spaces.Dict:
        """Nested `Dict`: per agent, its keys in the original's insertion order."""
        per_agent = {}
        for i, agent in enumerate(self.agents):
            keys = {}
            for stem, _, _, size, bounded in self.entries:
                low, high = (0.0, 1.0) if bounded else (-np.inf, np.inf)
                keys[f"{stem}_{i}"] = gymnasium.spaces.Box(low, high, (size,), np.float32)
            per_agent[agent] = gymnasium.spaces.Dict(keys, sort_keys=False)
        return gymnasium.spaces.Dict(per_agent, sort_keys=False)

    def __call__(self, obs: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
        obs = {k: np.asarray(v, np.float32) for k, v in obs.items()}
        return {
            agent: {
                f"{stem}_{i}": obs[source][i][index] for stem, source, index, _, _ in self.entries
            }
            for i, agent in enumerate(self.agents)
        }
