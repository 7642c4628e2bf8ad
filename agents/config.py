"""The configuration of a PPO run: one frozen, hashable dataclass, validated on construction.

Every check runs when a :class:`PPOConfig` is built, so bad settings fail before anything is
compiled. The config is hashable so that it can be a static argument of jitted functions.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

import jaxgrid
from jaxgrid.constrained import language_table

COST_SOURCES = ("checker", "monitor")  # the checker's alarms; the monitor's costly steps


@dataclasses.dataclass(frozen=True)
class Mode:
    """A reward mode: where its cost comes from and what the learner does with it.

    ``sources`` are the cost sources (:data:`COST_SOURCES`) it can learn from, its default
    first (none: it learns from the env reward alone). The cost is a penalty on the reward
    (``penalty``), a constraint whose Lagrange multiplier moves by gradient steps or a PID
    controller (``multiplier``), a budget in the observation (``budget``), or a constraint on
    the policy update (``policy_update``); a ``shield`` masks the actions it judges costly.
    """

    sources: tuple[str, ...] = ()
    penalty: bool = False  # the training reward is the env reward minus penalty x cost
    multiplier: str | None = None  # "gradient" or "pid": how the Lagrange multiplier moves
    policy_update: str = "ppo"  # "ppo" (clipped ratio), "focops" or "cpo"
    budget: bool = False  # the remaining safety budget is observed, the reward cut once spent
    shield: bool = False  # the cost source vetoes actions (agents.shield)

    @property
    def cost_critic(self) -> bool:
        """Whether the learner estimates the cost's advantage (a cost critic and its GAE)."""
        return self.multiplier is not None or self.policy_update != "ppo"


# Every reward mode, in display order: the paper's method first, then its baselines, then the
# shields (tables and figures use it).
MODES = {
    "checker": Mode(("checker",), penalty=True),
    "shaped": Mode(("monitor",), penalty=True),
    "none": Mode(),
    "lagrangian": Mode(COST_SOURCES, multiplier="gradient"),
    "pid_lagrangian": Mode(COST_SOURCES, multiplier="pid"),
    "saute": Mode(COST_SOURCES, budget=True),
    "cpo": Mode(COST_SOURCES, policy_update="cpo"),
    "focops": Mode(COST_SOURCES, multiplier="gradient", policy_update="focops"),
    "shield": Mode(("checker",), shield=True),
    "shield_monitor": Mode(("monitor",), shield=True),
}
REWARD_MODES = tuple(MODES)


def either_source(mode: str) -> tuple[str, ...]:
    """The cost sources that ``mode`` can be switched between (``PPOConfig.cost_source``):
    all of :data:`COST_SOURCES` for the modes that can learn from either, else none."""
    return MODES[mode].sources if len(MODES[mode].sources) > 1 else ()


# The modes the paper's experiments compare (``python -m experiments.two_rooms`` trains them).
PAPER_MODES = ("checker", "shaped", "none", "lagrangian", "shield", "shield_monitor")
# Hyperparameters that can differ between the agents of one compiled program (a sweep):
# they become traced per-agent values (``RunnerState.hparams``) instead of constants.
SWEEPABLE = ("penalty", "checker_threshold", "cost_limit", "ent_coef", "lr")
# Settings renamed since runs were first saved, old name -> new name: a saved run's settings
# and sweeps (run.json, an experiment's config.json) are read under the new names.
RENAMED = {"cost_target": "cost_limit"}


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Everything that defines a training run (hashable, so it can be a static argument).

    The defaults are the agents of the paper's experiments (``python -m experiments.two_rooms``
    trains ``PPOConfig(env_id="TwoRooms-v0")`` in each reward mode); a scenario that needs
    another value says so in its row of :data:`experiments.presets.EXPERIMENTS`.

    Reward modes (:data:`REWARD_MODES`): ``none`` env reward; ``shaped`` env reward minus
    ``penalty`` on every ground-truth violation (the paper's hand-shaped baseline);
    ``checker`` env reward minus ``penalty`` whenever the checker's violation probability for
    the window ending at the new observation exceeds ``checker_threshold`` (``soft_checker``:
    minus ``penalty`` times the probability); ``lagrangian`` PPO-Lagrangian with the
    checker's alarms as the cost, a cost critic, and a multiplier learned to hold the alarms
    per episode at ``cost_limit`` (with ``cost_source="monitor"`` the cost is the monitor's
    instead: 1 on each step with a costly event, the safe-RL convention);
    ``pid_lagrangian`` the same with the multiplier set by a PID controller on the cost per
    episode (Stooke, Achiam and Abbeel 2020; :func:`agents.losses.pid_update`: ``pid_kp``
    on its excess over ``cost_limit``, ``pid_ki`` on the excess summed and clipped at 0,
    ``pid_kd`` on its rise since the last update), so that it reacts at once to a cost that
    appears and stops pushing as soon as the cost is back under the limit; ``saute`` PPO on
    the env reward, with the episode's remaining safety budget in the observation (Sootla et
    al. 2022: 1 at the episode's start, less the cost over ``cost_limit`` at each step;
    :func:`agents.evaluation.spend`) and, once it is overspent, a training reward of
    ``-saute_penalty`` on every step, so that the budget the policy observes tells it what the
    rest of the episode is worth; ``focops`` FOCOPS (Zhang, Vuong and Ross 2020;
    :func:`agents.losses.focops_loss`): the clipped ratio gives way to a first-order loss that
    pulls the policy towards the old one reweighted by ``exp((A - nu * A_cost) / focops_lam)``
    and drops the samples whose KL to the old policy exceeds ``focops_max_kl``, its multiplier
    ``nu`` moving as the Lagrangian's, capped at ``focops_nu_max``; ``cpo`` CPO (Achiam et
    al. 2017; :func:`agents.losses.cpo_step`): each update's policy step is the solution of
    the problem linearised at the acting policy, within the trust region ``cpo_max_kl`` and
    under the cost constraint (a recovery step that only lowers the cost where it is
    infeasible), then PPO's epochs fit the value heads alone; ``shield``
    removes, before each step, the actions whose candidate next window the checker scores
    above ``checker_threshold`` (:mod:`agents.shield`), and ``shield_monitor`` those whose
    candidate step the ground-truth monitor flags. Both shields add ``penalty`` times the
    policy's own probability of the blocked actions to the loss, so that the policy itself
    learns what was blocked.

    With ``alarm_onset`` the ``checker`` and ``lagrangian`` signals count only the step that
    raises an alarm, not its repeats while it stays up (an ablation: ``docs/decisions.md``).
    With ``alarm_forward`` an alarm is charged to the episode's next step, and only if that
    step moves forward: the alarm says the next step may violate, and only moving forward
    enters a cell. The step that raised the alarm (a turn towards a forbidden door, say) is
    not charged, so an agent is not taught to stay away from what it may face.

    The penalty of ``shaped``, ``checker`` and the shields is 0 for the first
    ``penalty_start`` fraction of the updates (0 by default: the constraint acts from the
    first update), then ramps linearly to ``penalty`` over the next ``penalty_warmup``
    fraction; the Lagrangian multiplier stays at ``lagrangian_init`` until the ramp begins.
    The shields block from the first step whatever ``penalty_start``. With ``penalty_gate``
    g > 0 the penalty is also scaled by min(1, s / g), s the fraction of the previous
    update's finished training episodes that reached the goal (0 before the first): it
    stays small while the agent rarely reaches the goal, and shrinks again when a penalised
    agent stops reaching it.

    With ``end_episode`` the ``shaped`` and ``checker`` modes also end the training episode
    where their signal fires (a violation, an alarm; OmniSafe's early-termination baseline):
    the step is terminal, so the agent loses what the rest of the episode was worth, a cost
    that is small while the agent cannot reach the goal and grows as it learns to.

    ``novelty_bonus`` (0: off) adds an episodic exploration bonus to the training reward
    whenever a step reaches a (cell, carrying or not) pair not yet visited in the episode,
    annealed linearly to 0 over the first ``novelty_anneal`` of training (then 0). With
    ``novelty_carrying`` False it pays for new cells, whatever is carried: picking up an
    object and walking the same room again then pays nothing. With
    ``novelty_changes`` it also pays for the first change of each grid cell in the episode
    (a door opened or unlocked, an object picked up or dropped): the cell of a door that
    opens is not new, but what lies behind it is. With ``novelty_claim`` K > 0 an episode is
    paid for new pairs (and changes) until it has K of them, its start included, and the step
    that reaches the goal is also paid for those it lacks: every successful episode earns the
    same K - 1 bonuses whatever its route, so a tour of the rooms never pays more than the goal.
    Evaluations, returns and success rates use the env reward only.

    The run is :attr:`num_chunks` chunks of ``eval_every`` updates of :attr:`batch_size`
    steps; ``total_timesteps`` is rounded down to whole chunks, and every schedule (learning
    rate, penalty ramp, novelty anneal) spans the :attr:`num_updates` updates actually run.
    ``conv_channels`` are the 3x3 convolutions of the policy's view encoder (``()``: an MLP
    over the FiLM-ed cell features). Why the defaults are what they are is recorded in
    ``docs/decisions.md``.
    """

    env_id: str = "TwoRooms-v0"  # jaxgrid id of the environment
    # overrides passed to jaxgrid.make, as (name, value) pairs
    env_kwargs: tuple[tuple[str, Any], ...] = ()
    num_envs: int = 128  # environments stepped in parallel
    num_steps: int = 64  # rollout steps per environment per update
    total_timesteps: int = 1_500_000  # env steps of the run, rounded down to whole chunks
    update_epochs: int = 4  # passes over each rollout
    num_minibatches: int = 4  # minibatches per pass
    lr: float = 1e-3  # Adam step size
    anneal_lr: bool = True  # anneal the step size linearly to 0 over the run
    gamma: float = 0.99  # discount
    gae_lambda: float = 0.95  # GAE's lambda
    clip_eps: float = 0.2  # PPO's ratio and value clip
    ent_coef: float = 0.01  # entropy bonus
    vf_coef: float = 0.5  # value-loss weight
    max_grad_norm: float = 0.5  # global gradient-norm clip
    reward_mode: str = "none"  # one of REWARD_MODES
    # where the cost comes from, one of COST_SOURCES that the mode can use; None: its own
    # (MODES[reward_mode].sources[0]: lagrangian and the constrained modes use the checker)
    cost_source: str | None = None
    # reward subtracted per violation (shaped) or alarm (checker); shields: weight of the
    # policy's probability of blocked actions in the loss
    penalty: float = 1.0
    penalty_start: float = 0.0  # fraction of the run before the penalty acts (an ablation)
    # fraction of the run over which the penalty ramps up: a full penalty from the start stops
    # agents before any door (docs/decisions.md)
    penalty_warmup: float = 0.5
    # scale the penalty by the last update's training success rate over this value, capped
    # at 1 (0: off)
    penalty_gate: float = 0.0
    checker_threshold: float = 0.5  # checker probability above which it alarms
    soft_checker: bool = False  # penalise the checker's probability instead of its alarm
    # checker, lagrangian: only the step that raises an alarm counts, not its repeats while
    # the alarm stays up (the ground truth counts a violation once, on entering)
    alarm_onset: bool = False
    # checker, lagrangian: charge an alarm to the next step of the episode if it moves forward
    # (the step the alarm predicts a violation of), not to the step that raised it: without
    # it, checker agents stop before the doors (docs/decisions.md)
    alarm_forward: bool = True
    # the constrained modes: cost per episode to hold (alarms, or the monitor's costly steps)
    cost_limit: float = 0.05
    lagrangian_lr: float = 0.05  # Lagrangian: multiplier step size
    lagrangian_init: float = 0.0  # Lagrangian: starting multiplier
    # PID Lagrangian: the multiplier's gains on the cost error, its integral and the cost's rise
    pid_kp: float = 1.0
    pid_ki: float = 0.05
    pid_kd: float = 0.1
    # Saute: the training reward of every step once the episode's budget is overspent is
    # -saute_penalty (0: the reward is cut)
    saute_penalty: float = 0.0
    # FOCOPS: the temperature of its reweighted policy, the KL above which a sample is dropped,
    # and the cap of its multiplier (which moves as the Lagrangian's, by lagrangian_lr)
    focops_lam: float = 1.5
    focops_max_kl: float = 0.02
    focops_nu_max: float = 2.0
    # CPO: the trust region (mean KL to the acting policy), conjugate-gradient steps, and the
    # damping added to the Fisher matrix
    cpo_max_kl: float = 0.01
    cpo_cg_iters: int = 10
    cpo_damping: float = 0.1
    # CPO: the Fisher-vector products average the KL over every this many samples (whole env
    # sequences of a recurrent policy), for a fraction of their cost (OmniSafe's is 4)
    cpo_fisher_every: int = 4
    novelty_bonus: float = 0.01  # episodic bonus per new (cell, carrying) pair, annealed to 0
    novelty_changes: bool = False  # the bonus also pays for each cell's first change per episode
    # the bonus pays for (cell, carrying) pairs; False: for cells, whatever is carried
    novelty_carrying: bool = True
    novelty_anneal: float = 1.0  # fraction of the run over which the bonus falls to 0
    # the most bonuses an episode earns (0: no cap); reaching the goal pays what is left
    novelty_claim: int = 0
    # end the training episode where the shaping signal fires (shaped: a violation; checker:
    # an alarm), as well as subtracting the penalty: the agent loses the episode's future
    end_episode: bool = False
    eval_every: int = 10  # updates between evaluations (one chunk)
    eval_episodes: int = 50  # fixed-seed episodes per evaluation
    eval_seed: int = 20_200_207  # key of the evaluation episodes, shared by every method
    seed: int = 0  # seed of a single run
    conv_channels: tuple[int, ...] = (16,)  # 3x3 convolutions of the view encoder; () for an MLP
    # a GRU memory in the policy, carried through each episode; updates then take minibatches
    # of whole env sequences and backpropagate through time (PureJaxRL's ppo_rnn)
    recurrent: bool = False
    cell_dim: int = 8  # features per view cell, which the sentence scales and shifts (FiLM)
    # the sentence also scales each view cell's one-hot object, colour and state codes before
    # they are embedded, so that it can weigh one colour against the others directly: without
    # it, checker agents stop before the doors (docs/decisions.md)
    film_codes: bool = True
    # a recurrent policy's heads read the step's observation features beside the memory,
    # not only through the GRU's gated update
    memory_skip: bool = False

    def __post_init__(self):
        try:  # a dict or pairs -> sorted pairs, so that the config stays hashable
            pairs = tuple(sorted(dict(self.env_kwargs).items()))
            hash(pairs)
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"PPOConfig.env_kwargs must be (name, hashable value) pairs or a dict, got "
                f"{self.env_kwargs!r}"
            ) from e
        object.__setattr__(self, "env_kwargs", pairs)
        positive = (
            "num_envs", "num_steps", "total_timesteps", "update_epochs", "num_minibatches",
            "eval_every", "eval_episodes", "cpo_cg_iters", "cpo_fisher_every",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"PPOConfig.{name} must be a positive integer, got {value!r}")
        for name in ("seed", "eval_seed"):  # PRNG keys of 32-bit seeds
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or not 0 <= value < 2**31:
                raise ValueError(f"PPOConfig.{name} must be an integer in [0, 2**31), got "
                                 f"{value!r}")  # fmt: skip
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float | np.floating) and not math.isfinite(value):
                raise ValueError(f"PPOConfig.{f.name} must be finite, got {value!r}")
        for name in ("lr", "clip_eps", "max_grad_norm", "focops_lam", "focops_max_kl",
                     "cpo_max_kl", "cpo_damping"):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ValueError(f"PPOConfig.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("gamma", "gae_lambda", "penalty_start", "penalty_warmup", "penalty_gate"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"PPOConfig.{name} must be in [0, 1], got {getattr(self, name)}")
        if not 0 < self.novelty_anneal <= 1:
            raise ValueError(
                f"PPOConfig.novelty_anneal must be in (0, 1], got {self.novelty_anneal}"
            )
        claim = self.novelty_claim
        if isinstance(claim, bool) or not isinstance(claim, int | np.integer) or claim < 0:
            raise ValueError(f"PPOConfig.novelty_claim must be an int >= 0, got {claim!r}")
        if claim and not self.novelty_bonus:
            raise ValueError("PPOConfig.novelty_claim needs a novelty_bonus > 0 to pay out")
        if not 0 < self.checker_threshold < 1:  # 0 or 1 would alarm always or never
            raise ValueError(
                f"PPOConfig.checker_threshold must be in (0, 1), got {self.checker_threshold}"
            )
        nonnegative = (
            "ent_coef",
            "vf_coef",
            "penalty",
            "cost_limit",
            "lagrangian_lr",
            "lagrangian_init",
            "pid_kp",
            "pid_ki",
            "pid_kd",
            "saute_penalty",
            "focops_nu_max",
            "novelty_bonus",
        )
        for name in nonnegative:
            if not getattr(self, name) >= 0:
                raise ValueError(f"PPOConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        convs = self.conv_channels
        if not isinstance(convs, tuple | list) or not all(
            isinstance(c, int | np.integer) and not isinstance(c, bool) and c > 0 for c in convs
        ):
            raise ValueError(
                f"PPOConfig.conv_channels must be a tuple of positive ints, got {convs!r}"
            )
        object.__setattr__(self, "conv_channels", tuple(int(c) for c in convs))
        dim = self.cell_dim
        if isinstance(dim, bool) or not isinstance(dim, int | np.integer) or dim < 1:
            raise ValueError(f"PPOConfig.cell_dim must be a positive int, got {dim!r}")
        if self.memory_skip and not self.recurrent:
            raise ValueError("PPOConfig.memory_skip needs recurrent=True: it skips the memory")
        if self.reward_mode not in REWARD_MODES:
            raise ValueError(
                f"PPOConfig.reward_mode must be one of {REWARD_MODES}, got {self.reward_mode!r}"
            )
        sources = MODES[self.reward_mode].sources
        if self.cost_source is not None and self.cost_source not in COST_SOURCES:
            raise ValueError(f"PPOConfig.cost_source must be None or one of {COST_SOURCES}, "
                             f"got {self.cost_source!r}")  # fmt: skip
        if self.cost_source is not None and self.cost_source not in sources:
            uses = f"learns from the {' or the '.join(sources)} only" if sources else "has no cost"
            raise ValueError(
                f"PPOConfig.cost_source={self.cost_source!r}: reward_mode={self.reward_mode!r} "
                f"{uses} (leave cost_source None)"
            )
        if self.alarm_forward and (self.alarm_onset or self.soft_checker):
            raise ValueError(
                "PPOConfig.alarm_forward charges the previous step's alarm; it does not combine "
                f"with alarm_onset={self.alarm_onset} or soft_checker={self.soft_checker}"
            )
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"PPOConfig.num_minibatches ({self.num_minibatches}) must divide num_envs x "
                f"num_steps ({self.batch_size})"
            )
        if self.num_envs % self.num_minibatches:
            raise ValueError(
                f"PPOConfig.num_envs ({self.num_envs}) must be divisible by num_minibatches "
                f"({self.num_minibatches})"
            )
        if self.num_chunks < 1:
            updates = self.total_timesteps // self.batch_size
            raise ValueError(
                f"PPOConfig.total_timesteps ({self.total_timesteps}) gives {updates} "
                f"updates of {self.batch_size} steps (num_envs x num_steps), fewer than one "
                f"evaluation chunk of {self.eval_every} update(s): it must be at least "
                f"{self.batch_size * self.eval_every}"
            )

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_chunks(self) -> int:
        """Evaluation chunks of ``eval_every`` updates (the run is rounded down to whole ones)."""
        return (self.total_timesteps // self.batch_size) // self.eval_every

    @property
    def num_updates(self) -> int:
        """Updates actually run (``num_chunks * eval_every``): what every schedule spans."""
        return self.num_chunks * self.eval_every

    @property
    def mode(self) -> Mode:
        """The reward mode's row of :data:`MODES`."""
        return MODES[self.reward_mode]

    @property
    def cost_from(self) -> str | None:
        """The cost source of the run: ``cost_source``, else the mode's own (None: no cost)."""
        sources = self.mode.sources
        return self.cost_source if self.cost_source is not None else (sources or (None,))[0]

    @property
    def uses_checker(self) -> bool:
        return self.cost_from == "checker"

    @property
    def shield_judge(self) -> str | None:
        """``"checker"`` or ``"monitor"`` in the shield modes, else None."""
        return self.cost_from if self.mode.shield else None

    def make_env(self):
        return jaxgrid.make(self.env_id, **dict(self.env_kwargs))


def check_checker(config: PPOConfig, checker, env) -> None:
    """Fail fast, before any compile, when the checker does not fit the run."""
    if config.uses_checker and checker is None:
        instead = ", or learn from the monitor's cost: cost_source='monitor'"
        raise ValueError(
            f"PPOConfig.reward_mode={config.reward_mode!r} learns from the checker's alarms and "
            "needs a trained checker: pass checker=checker.load(DIR) (or train one with "
            f"`python -m checker`){instead if 'monitor' in config.mode.sources else ''}"
        )
    if checker is not None and checker.config.view_size != env.view_size:
        raise ValueError(
            f"checker view_size {checker.config.view_size} != env view_size {env.view_size}"
        )
    words = language_table(env).vocab_size
    if checker is not None and checker.config.vocab_size != words:
        raise ValueError(
            f"the checker reads a vocabulary of {checker.config.vocab_size} token ids and "
            f"{config.env_id} speaks one of {words}: train the checker on this env's language "
            "(a HazardRooms env needs a memory checker: python -m checker --kind memory)"
        )


def renamed(settings: dict) -> dict:
    """``settings`` {name: value} with the names of :data:`RENAMED` replaced by the new ones,
    so that what an older version saved reads as today's settings."""
    return {RENAMED.get(name, name): value for name, value in settings.items()}


def check_sweep(sweep, config: PPOConfig | None = None) -> dict[str, tuple[float, ...]]:
    """``sweep`` {name: values} as {name: distinct floats} in the given order ({} for None).

    A name of :data:`RENAMED` is read as its new name. ``ValueError`` naming the problem for
    a name not in :data:`SWEEPABLE`, no or repeated values, or a value that ``config``
    (default: the defaults) would refuse.
    """
    out = {}
    for name, values in renamed(dict(sweep or {})).items():
        if name not in SWEEPABLE:
            raise ValueError(f"cannot sweep {name!r}: sweepable are {', '.join(SWEEPABLE)}")
        try:
            values = tuple(float(v) for v in values)
        except (TypeError, ValueError):
            raise ValueError(f"sweep {name}: values must be numbers, got {values!r}") from None
        if not values or len(set(values)) != len(values):
            raise ValueError(f"sweep {name}: give distinct values, got {list(values)}")
        for v in values:  # each value must make a valid config on its own
            dataclasses.replace(config or PPOConfig(), **{name: v})
        out[name] = values
    return out
