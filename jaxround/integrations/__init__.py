"""Thin views of the one JAX environment for other RL libraries: a gymnax
`Environment` (`gymnax_env`) and a JaxMARL `MultiAgentEnv` (`jaxmarl_env`).

Each adapts `jaxround.envs.roundabout.RoundaboutEnv`'s `step_env` and
`observation` and keeps no copy of the step, the observers or the rewards.
They import their library inside the module: ``pip install "jaxround[gymnax]"``
or ``"jaxround[jaxmarl]"``. The same environment over real SUMO, for
PettingZoo and Gymnasium, is `sumo_export.pettingzoo_env`.
"""
