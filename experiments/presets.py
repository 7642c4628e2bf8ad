"""The experiments, one row each, and the presets: every setting that differs from the
defaults of :class:`~experiments.pipeline.ExperimentConfig` (whose parts are
:class:`~agents.config.PPOConfig`, :class:`~checker.train.CheckerTrainConfig` and
:class:`~checker.memory.MemoryTrainConfig`, each with its experiments' values as defaults) is
declared here once, with its reason.

:func:`experiments.pipeline.preset` builds a row's configuration: the base with the row's
env ids and checker kind, then the row's ``changes``, then the preset's, then the row's step
budget for that preset. A change is a dict of field values; a dict value changes a nested
part (``ppo``, ``checker_train``, ``memory_checker``).
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One experiment: what ``python -m experiments.<name>`` runs."""

    name: str  # names the module, the outputs and the default --out
    env_id: str  # the compared agents' scenario
    checker_env_id: str | None = None  # the checker's scenario; None: env_id
    # "window" (the paper's) or "memory": experiments.checker_phases.CHECKER_PHASES, which
    # also hides the flags of the other kinds' settings
    checker_kind: str = "window"
    # settings that differ from the base in every preset (the reasons beside them)
    changes: dict = dataclasses.field(default_factory=dict)
    # the preset's step budgets for this experiment, applied after the preset
    budgets: dict[str, dict] = dataclasses.field(default_factory=dict)
    # settings without a flag in its command line: a field of ExperimentConfig (a nested
    # part: all its flags) or "part.field"
    hidden: tuple[str, ...] = ()


# Sizes of every experiment: changes of the default preset (the base).
PRESETS: dict[str, dict] = {
    # Meaningful results within about 30 minutes on a 2-core CPU.
    "default": {},
    # --quick: the outputs and their schema, in minutes; results mean nothing.
    "quick": dict(quick=True, machine_baseline=False, seeds=2, behaviour_steps=8_192,
                  checker_samples=512, collect_max_steps=256, curve_points=2, final_episodes=32,
                  checker_train=dict(epochs=3),
                  memory_checker=dict(streams=16, steps=48, updates=10, batch_streams=8),
                  ppo=dict(total_timesteps=16_384, num_envs=32, eval_episodes=16)),
    # --paper: the paper's budget (1e7 steps), 10 seeds, 50 evaluation episodes a checkpoint.
    "paper": dict(paper=True, seeds=10, behaviour_steps=1_000_000, curve_points=40,
                  checker_train=dict(epochs=60),
                  ppo=dict(total_timesteps=10_000_000, num_envs=256)),
}  # fmt: skip

# HazardRooms' sentences: one or two of each constraint type of jaxgrid.language;
# budgets and the trigger concern hazards across the routes.
HAZARD_SENTENCES = (
    "avoid lava",
    "do not step on lava more than twice",
    "after you pick up the key, do not use the red door",
    "never stand next to lava",
    "stay away from water and use the red door at most once",
)


def constrained_level(name: str, env_id: str, sentence: str, **env) -> Experiment:
    """A MiniGrid level with a constraint (``jaxgrid.make(env_id, constraint=sentence,
    **env)``), trained as HazardRooms is: a memory checker and a recurrent policy, since a
    budget is a count, and the memory checker's label of the step into each frame, which
    the shield asks about."""
    return Experiment(name, env_id, checker_kind="memory", changes=dict(
        memory_checker=dict(lookahead=0),
        ppo=dict(env_kwargs=(("constraint", sentence), *env.items()), recurrent=True,
                 # measured on the paper scenarios' window checker, not on a memory checker
                 film_codes=False, alarm_forward=False),
    ))  # fmt: skip


EXPERIMENTS: dict[str, Experiment] = {e.name: e for e in (
    # The paper's 2Rooms.
    Experiment("two_rooms", "TwoRooms-v0"),
    # The paper's 2Rooms-Lava: lava's detour takes longer to solve at all, and a behaviour
    # agent trained longer meets doors and lava more often (docs/decisions.md).
    Experiment("two_rooms_lava", "TwoRoomsLava-v0", budgets={
        "default": dict(behaviour_steps=600_000, ppo=dict(total_timesteps=3_000_000))}),
    # The paper's generalisation experiment: ThreeRooms-Key agents with a TwoRooms checker.
    # At 3M steps one seed in three or four never passed the locked door, at 5M none of 10.
    Experiment("three_rooms_key", "ThreeRoomsKey-v0", "TwoRooms-v0", budgets={
        "default": dict(ppo=dict(total_timesteps=5_000_000))}),
    # Constraints that count, wait for a trigger or keep a distance (docs/decisions.md).
    Experiment("hazard_rooms", "HazardRooms-v0", checker_kind="memory", changes=dict(
        # a frame and the episode's memory determine the step into it, and a shield asks
        # about the frame each candidate action leads to
        memory_checker=dict(lookahead=0),
        # the shield's own checker: half its streams' actions from the oracle, so that they
        # pass the doors as trained agents do (fewer false alarms in whole episodes)
        shield_guided=0.5,
        ppo=dict(
            env_kwargs=(("sentences", HAZARD_SENTENCES),),  # the learner encodes a fixed table
            recurrent=True,  # the policy counts, as the checker does
            novelty_bonus=0.05,  # behind two closed doors the goal is too rare a find
            novelty_claim=60,  # touring the rooms never pays more than the goal
            novelty_carrying=False,  # with the key in hand the first room would pay twice
            # measured on the paper scenarios' window checker, not on this memory checker
            film_codes=False, alarm_forward=False,
        ),
    )),  # fmt: skip
    # MiniGrid levels with a constraint of each kind: lava that costs instead of ending the
    # episode, so that a budget means something; a door colour the level draws at random
    # (an episode without a red door has a vacuous constraint); a distance from lethal lava.
    constrained_level("lava_crossing", "MiniGrid-LavaCrossingS9N1-v0",
                      "do not step on lava more than twice", lava="cost"),
    constrained_level("lava_gap", "MiniGrid-LavaGapS7-v0", "avoid lava", lava="cost"),
    constrained_level("multi_room", "MiniGrid-MultiRoom-N2-S4-v0", "do not use the red door"),
    constrained_level("dist_shift", "MiniGrid-DistShift1-v0", "never stand next to lava"),
    # Ablation: just-before (lookahead 1) against "after" (0) labels, TwoRooms in checker
    # mode (experiments.label_timing). Both arms lack what exists only at lookahead 1 (the
    # blocked and lava counterfactuals) or charges the step after an alarm.
    Experiment("label_timing", "TwoRooms-v0", changes=dict(
        modes=("checker",), ppo=dict(alarm_forward=False),
        checker_train=dict(blocked=0, lava_counterfactuals=False)),
        # set by the ablation itself; a given --checker has one labelling, not the two compared
        hidden=("modes", "checker", "checker_train.lookahead")),
)}  # fmt: skip

#: The levels of ``python -m experiments.benchmark``: rows of :data:`EXPERIMENTS`.
BENCHMARK_LEVELS: tuple[str, ...] = (
    "two_rooms", "two_rooms_lava", "three_rooms_key", "hazard_rooms",
    "lava_crossing", "lava_gap", "multi_room", "dist_shift",
)  # fmt: skip
