"""mpo_plant: serve a plant to the `mpo` learner from another process, over iceoryx2.

    python3 -m mpo_plant --gym Pendulum-v1          # any Gymnasium environment

or, from a robot's own program:

    import mpo_plant

    class Robot:
        obs_size, act_size = 11, 2
        action_low, action_high = [-1.0, -1.0], [1.0, 1.0]
        def reset(self, seed): ...             # -> first observation
        def step(self, action): ...            # -> (observation, reward, terminated, truncated)

    mpo_plant.serve(Robot, single_instance=True)   # run id from MPO_PLANT_RUN

The protocol and what a plant must implement: docs/external-plant.md in the repository.
"""

from .protocol import PROTOCOL_VERSION
from .server import PlantFailed, serve

__all__ = ["PROTOCOL_VERSION", "PlantFailed", "serve", "GymPlant"]


def __getattr__(name):
    # Gymnasium is imported only by those who use it.
    if name == "GymPlant":
        from .gym import GymPlant

        return GymPlant
    raise AttributeError(name)
