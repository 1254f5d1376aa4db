"""2-D scene simulator with exact ground-truth flow.

``world`` builds floor plans, ``people`` walks two-legged people, ``platform`` drives the robot,
``lidar`` casts rays, ``groundtruth`` computes the flow and ``scenario`` puts it all together:
``simulate(frames, seed, SimConfig(scenario="dynamic"))`` returns a
:class:`lidarflow.data.Recording` whose ``extras`` hold the ground truth.
"""

from lidarflow.sim.groundtruth import ground_truth
from lidarflow.sim.lidar import PRESETS, LidarConfig, cast_rays, lidar_preset, measure
from lidarflow.sim.people import PeopleConfig
from lidarflow.sim.platform import PlatformConfig
from lidarflow.sim.scenario import SimConfig, simulate, simulate_episode, write_simulation
from lidarflow.sim.storage import dense_flow
from lidarflow.sim.world import WorldConfig, build_world

__all__ = [
    "PRESETS",
    "LidarConfig",
    "PeopleConfig",
    "PlatformConfig",
    "SimConfig",
    "WorldConfig",
    "build_world",
    "cast_rays",
    "dense_flow",
    "ground_truth",
    "lidar_preset",
    "measure",
    "simulate",
    "simulate_episode",
    "write_simulation",
]
