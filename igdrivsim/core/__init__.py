"""What the maze and the driving benchmark share: the episode runner, the RL loss terms, the SGD
loop, the network parts and the method parameters.

:mod:`igdrivsim.core.episode` runs an :class:`~igdrivsim.core.episode.Actor` in an environment
(``lax.scan``); :mod:`igdrivsim.core.learn` holds GAE, the PPO terms, the imitation terms of
categorical policies and every learner's epochs of minibatch steps; :mod:`igdrivsim.core.nn`
the recurrent and dense parts of both networks; :mod:`igdrivsim.core.params` the
hyper-parameters both read, with one default each. All depend on JAX alone (no other igdrivsim
module), so any environment can build on them.
"""
