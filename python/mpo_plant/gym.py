"""Any Gymnasium environment with a continuous (Box) action space, as a plant."""

import numpy as np


class GymPlant:
    """A Gymnasium environment behind the plant interface `serve` expects.

    The observation is flattened (`gymnasium.spaces.flatten`), so Dict and Tuple observation
    spaces work too; the action space must be a Box (MPO acts continuously). Seeds follow
    Gymnasium: a fresh instance's first reset is `env.reset(seed=seed)`, later ones
    `env.reset()`. An episode ends when `terminated or truncated`; it ends in a terminal state
    (discount 0) only when `terminated`.
    """

    def __init__(self, env_id: str, **kwargs):
        import gymnasium

        self.env = gymnasium.make(env_id, **kwargs)
        self.obs_space = self.env.observation_space
        space = self.env.action_space
        if not isinstance(space, gymnasium.spaces.Box):
            raise ValueError(
                f"{env_id}: the action space {space} is not a Box; MPO acts continuously"
            )
        self._flatten = gymnasium.spaces.flatten
        self._act_dtype = space.dtype
        self._act_shape = space.shape
        self.name = f"gymnasium {env_id}"
        self.obs_size = int(gymnasium.spaces.flatdim(self.obs_space))
        self.act_size = int(np.prod(space.shape))
        self.action_low = np.asarray(space.low, dtype=np.float64).ravel()
        self.action_high = np.asarray(space.high, dtype=np.float64).ravel()
        spec = self.env.spec
        self.episode_steps = int(spec.max_episode_steps or 0) if spec is not None else 0

    def _obs(self, obs) -> np.ndarray:
        return np.asarray(self._flatten(self.obs_space, obs), dtype=np.float64)

    def reset(self, seed):
        obs, _info = self.env.reset(seed=seed)
        return self._obs(obs)

    def step(self, action):
        a = np.asarray(action, dtype=self._act_dtype).reshape(self._act_shape)
        obs, reward, terminated, truncated, _info = self.env.step(a)
        return self._obs(obs), float(reward), bool(terminated), bool(truncated)

    def close(self):
        self.env.close()
