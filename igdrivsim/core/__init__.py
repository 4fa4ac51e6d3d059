"""What the maze and the driving benchmark share: the episode runner and the RL loss terms.

:mod:`igdrivsim.core.episode` runs an :class:`~igdrivsim.core.episode.Actor` in an environment
(``lax.scan``); :mod:`igdrivsim.core.losses` holds GAE, the PPO terms and the imitation terms of
categorical policies. Both depend on JAX alone, so any environment can build on them.
"""
