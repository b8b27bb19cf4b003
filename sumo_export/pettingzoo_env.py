"""The roundabout in real SUMO as a PettingZoo `ParallelEnv`, each AV an agent.
Installed by ``pip install "jaxround[pettingzoo]"``.

    env = SumoParallelEnv(load_config("milan"), penetration=0.5)
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: policy(obs[a]) for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    env.close()

The same functions as the JAX environment, none copied:

- observation: each AV's row of the scenario's observer, float32 (D,),
  computed by the JAX environment's own jitted observer on the vehicles read
  from libsumo (`sumo_export.traffic.SumoObserver`), as the exported
  policy's controller sees them.
- action: float32 (2,) per AV, the JAX environment's per-slot action
  (``agent.action: accel``: acceleration, clipped to [-decel, accel];
  ``assertiveness``: the raw assertiveness; then the lane column in
  [-1, 1], `jaxround.envs.lane_view`), sent to SUMO by the controller's own
  `PolicyController.command`.
- reward: `jaxround.envs.reward` (the scenario's ``agent.reward``) on the
  speeds and CO2 SUMO reports after the step (`sumo_export.sumo_reward`).

Agents appear as AVs are inserted and leave as they arrive (terminated) or
when the run reaches the scenario's horizon and drain (truncated). Steps in
which no AV is in the network are run without a call: `reset` and `step`
return when an AV is there or the run has ended (``agents`` empty). The
sequence of SUMO steps and commands is the one `sumo_export.runner` runs
with a controller, so a policy driven through this environment gives the
crossing times of ``jaxround evaluate --sim sumo`` (tests/sumo).

libsumo holds one simulation per process: one environment per process (a
second `reset` in another environment of the same process closes the first's
run). Several environments side by side need several processes: RLlib's
env runners, or Stable-Baselines3's ``SubprocVecEnv`` (see docs/integrations.md).
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from jaxround.envs.assertiveness import RAW_BOUND
from jaxround.envs.observe import OBSERVATION_SIZES
from jaxround.scenario.config import DRAIN_S, ScenarioConfig
from jaxround.scenario.schedule import Schedule, make_schedule
from jaxround.sumo_files.processes import in_child_process, pin_jax_to_cpu
from sumo_export.controller import PolicyController, PolicyFn
from sumo_export.runner import sumo_arguments
from sumo_export.scenario import vehicle_id, write_scenario
from sumo_export.sumo_reward import SumoReward
from sumo_export.traffic import DEFAULT_SLOTS, SumoTraffic


def _no_policy(obs: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    raise RuntimeError("the environment's actions come from step(), not a policy")


class SumoParallelEnv(ParallelEnv):
    """The scenario in libsumo, its AVs as PettingZoo agents (module docstring).

    Args:
        cfg: the scenario.
        penetration: AV share of the schedules `reset` draws (None: the
            config's).
        schedule: run this schedule at every reset instead of drawing one.
        observer: the observer's name (None: the config's ``agent.observer``).
        max_slots: vehicle slots of the observer (None: what the road holds);
            more vehicles than slots raise OverflowError.
        workdir: where each run's SUMO files go (None: a temporary folder).
        cpu_only: pin this process's JAX (the observer) to the CPU before it
            starts a backend (`jaxround.sumo_files.processes`); None: where
            the environment is built in a process of its own (a vector
            environment's worker), so that no worker takes the GPU; give
            True in an RLlib env runner (a Ray actor).

    Attributes:
        agents: ids of the AVs in the network (SUMO's ids, ``"v<index>"``).
        possible_agents: ids of every AV of the current schedule.
        time_s: SUMO's time.
        arrival_s: {vehicle id: arrival time} of this run's arrived vehicles,
            as SUMO's tripinfo gives it.
    """

    metadata = {"name": "jaxround_sumo_v0", "render_modes": []}

    def __init__(
        self,
        cfg: ScenarioConfig,
        penetration: float | None = None,
        schedule: Schedule | None = None,
        observer: str | None = None,
        max_slots: int | None = DEFAULT_SLOTS,
        workdir: str | Path | None = None,
        cpu_only: bool | None = None,
    ) -> None:
        if cpu_only or (cpu_only is None and in_child_process()):
            pin_jax_to_cpu()
        observer = cfg.agent.observer if observer is None else observer
        if observer not in OBSERVATION_SIZES:
            raise ValueError(
                f"observer {observer!r}, expected one of {sorted(OBSERVATION_SIZES)}"
            )
        if penetration is not None and not 0.0 <= penetration <= 1.0:
            raise ValueError(f"penetration: {penetration}, expected 0..1")
        self.cfg = cfg
        self.penetration = penetration
        self.fixed_schedule = schedule
        self.workdir = None if workdir is None else Path(workdir)
        self.schedule = schedule or make_schedule(cfg, penetration=penetration)
        self.controller = PolicyController(
            cfg, self.schedule, _no_policy, observer, max_slots, strict=True,
            action=cfg.agent.action,
        )  # fmt: skip
        self.reward = SumoReward(cfg, self.controller.sumo.max_slots)
        self.max_time_s = cfg.demand.duration_s + DRAIN_S
        self.dt = cfg.simulation.dt_s
        self.possible_agents = self._av_ids(self.schedule)
        self.agents: list[str] = []
        self.time_s = 0.0
        self.arrival_s: dict[str, float] = {}
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._libsumo: Any = None
        self._traffic: SumoTraffic | None = None
        self._obs: dict[str, np.ndarray] = {}
        self._rows = np.zeros((0, 0), np.float32)
        self._episode = 0

    # ------------------------------------------------------------------ spaces

    @functools.cache  # noqa: B019 (one space object per agent, as PettingZoo asks)
    def observation_space(self, agent: str) -> spaces.Box:
        d = OBSERVATION_SIZES[self.controller.sumo.env.observer]
        return spaces.Box(-np.inf, np.inf, (d,), np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        """float32 (2,): as `jaxround.integrations.gymnax_env.action_bounds`."""
        if self.cfg.agent.action == "assertiveness":
            low, high = (-RAW_BOUND, -1.0), (RAW_BOUND, 1.0)
        else:
            av = self.cfg.drivers.av
            low, high = (-av.decel, -1.0), (av.accel, 1.0)
        return spaces.Box(np.float32(low), np.float32(high), (2,), np.float32)

    # ------------------------------------------------------------------ API

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start a run: a new schedule (drawn with `seed`, else the config's
        seed plus the number of earlier resets) unless one was given."""
        del options
        self.close()
        if self.fixed_schedule is None:
            if seed is None:
                seed = self.cfg.simulation.seed + self._episode
            self.schedule = make_schedule(
                self.cfg, seed=seed, penetration=self.penetration
            )
        self._episode += 1
        self.possible_agents = self._av_ids(self.schedule)
        self.controller.start_episode(self.schedule)
        self._start()
        self.agents, self.arrival_s, self._traffic = [], {}, None
        self._advance_to_agents()
        return dict(self._obs), {a: {} for a in self.agents}

    def step(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Command the agents' actions, step SUMO, observe and reward.

        Args:
            actions: float (2,) for each agent in ``agents``; an agent left
                out drives its vType this step (its row is NaN: no command).

        Raises:
            RuntimeError: no run (call `reset`), or it has ended.
            ValueError: an action for an agent that is not in ``agents``.
        """
        if self._libsumo is None or not self.agents:
            raise RuntimeError("no agents to step: call reset() first")
        unknown = sorted(set(actions) - set(self.agents))
        if unknown:
            raise ValueError(f"actions for agents not in the network: {unknown}")
        traffic = self._traffic
        rows = np.full((traffic.n, 2), np.nan)
        for k, vid in enumerate(traffic.ids):
            if vid in actions:
                rows[k] = np.asarray(actions[vid], np.float64).reshape(2)
        self.controller.command(self._libsumo, traffic, rows[:, 0], rows[:, 1])
        acting = list(self.agents)
        self.reward.before_step(self._libsumo, acting)
        arrived = self._sumo_step()
        rewards = self.reward.after_step(self._libsumo, acting)
        zero = self._zero_row()
        if self._finished():
            # every vehicle left, or the horizon and drain are over
            cut = self.time_s >= self.max_time_s
            self._observe()
            obs = {a: self._obs.get(a, zero) for a in acting}
            self.agents, self._obs = [], {}
            self.close()
            terminated = {a: a in arrived or not cut for a in acting}
            truncated = {a: not terminated[a] for a in acting}
            return obs, rewards, terminated, truncated, {a: {} for a in acting}
        self._observe()
        still = set(self.agents)
        obs = {a: self._obs.get(a, zero) for a in acting}
        if not self.agents:  # the last AVs left: run on until the next comes
            self._advance_to_agents()
        obs.update(self._obs)
        # an agent that is no longer in the network arrived (or left its lane)
        terminated = {a: a not in still for a in acting}
        for a in self.agents:  # agents that came in with this step
            rewards.setdefault(a, 0.0)
            terminated.setdefault(a, False)
        truncated = dict.fromkeys(terminated, False)
        return obs, rewards, terminated, truncated, {a: {} for a in terminated}

    def slot_rows(self) -> tuple[list[str], np.ndarray]:
        """Every vehicle in the network and its observation row, as the
        controller reads them: (ids of the n vehicles in slot order, float32
        (n, D) rows; human drivers' rows included)."""
        if not self.agents:
            return [], np.zeros((0, self.observation_space("").shape[0]), np.float32)
        return list(self._traffic.ids), self._rows[: self._traffic.n]

    def policy_actions(self, act: PolicyFn) -> dict[str, np.ndarray]:
        """An exported policy's actions for the agents, float32 (2,) each,
        computed as its controller computes them: on the rows of every vehicle
        in the network at once (`PolicyController.decide`).

        NumPy's matrix products round by batch, so the policy on the agents'
        rows alone can differ in the last bits; this gives the controller's
        commands exactly.

        Args:
            act: ``act(obs (n, D), mask (n,)) -> (accel (n,), change (n,))``,
                e.g. `agents.common.export.load_policy_numpy`'s.
        """
        if not self.agents:
            return {}
        self.controller.act = act
        accel, change = self.controller.decide(self._rows, self._traffic)
        agents = set(self.agents)
        return {
            vid: np.array([accel[k], float(change[k])], np.float32)
            for k, vid in enumerate(self._traffic.ids)
            if vid in agents
        }

    def close(self) -> None:
        """End the run (libsumo's simulation of this process) and its files."""
        if self._libsumo is not None:
            self._libsumo.close()
            self._libsumo = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # ------------------------------------------------------------------ pieces

    def _av_ids(self, schedule: Schedule) -> list[str]:
        return [vehicle_id(int(i)) for i in np.nonzero(schedule.is_av)[0]]

    def _zero_row(self) -> np.ndarray:
        return np.zeros(self.observation_space("").shape, np.float32)

    def _start(self) -> None:
        import libsumo

        if self.workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="jaxround-pz-")
            out = Path(self._tmp.name)
        else:
            out = self.workdir
        files = write_scenario(self.cfg, self.schedule, out)
        libsumo.start(
            sumo_arguments(files.sumocfg, out / "tripinfo.xml", out / "stats.xml")
        )
        self._libsumo = libsumo
        self.time_s = float(libsumo.simulation.getTime())

    def _finished(self) -> bool:
        sim = self._libsumo.simulation
        return sim.getMinExpectedNumber() <= 0 or self.time_s >= self.max_time_s

    def _sumo_step(self) -> set[str]:
        """One SUMO step; the ids that arrived in it."""
        sim = self._libsumo.simulation
        sim.step()
        self.time_s = float(sim.getTime())
        arrived = set(sim.getArrivedIDList())
        for vid in arrived:  # as SUMO's tripinfo counts it: the step's start
            self.arrival_s[vid] = self.time_s - self.dt
        return arrived

    def _observe(self) -> None:
        """Read SUMO's vehicles; the AVs among them are the agents."""
        traffic = self.controller.sumo.read(self._libsumo)
        self._traffic = traffic
        is_av = traffic.column("is_av")[: traffic.n] > 0.5
        self.agents = [vid for vid, av in zip(traffic.ids, is_av) if av]
        if not self.agents:
            self._obs = {}
            return
        rows = self.controller.sumo.observe(traffic)
        self._rows = rows
        self._obs = {vid: rows[k] for k, vid in enumerate(traffic.ids) if is_av[k]}

    def _advance_to_agents(self) -> None:
        """Step SUMO, as the controller would with no AV to drive (it releases
        AVs that lost their slot), until an AV is in the network or the run
        ends."""
        while True:
            if self._traffic is not None:  # the controller's call without AVs
                self.controller.command(
                    self._libsumo, self._traffic, np.zeros(0), np.zeros(0)
                )
            self._sumo_step()
            if self._finished():
                self.agents, self._obs = [], {}
                self.close()
                return
            self._observe()
            if self.agents:
                return
