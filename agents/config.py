"""The configuration of a PPO run: one frozen, hashable dataclass, validated on construction.

Every check runs when a :class:`PPOConfig` is built, so bad settings fail before anything is
compiled. The config is hashable so that it can be a static argument of jitted functions.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

import jaxgrid

REWARD_MODES = ("none", "shaped", "checker", "lagrangian")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Everything that defines a training run (hashable, so it can be a static argument).

    Reward modes (:data:`REWARD_MODES`): ``none`` env reward; ``shaped`` env reward minus
    ``penalty`` on every ground-truth violation (the paper's hand-shaped baseline);
    ``checker`` env reward minus ``penalty`` whenever the checker's violation probability for
    the window ending at the new observation exceeds ``checker_threshold`` (``soft_checker``:
    minus ``penalty`` times the probability); ``lagrangian`` PPO-Lagrangian with the
    checker's alarms as the cost, a cost critic, and a multiplier learned to hold the alarms
    per episode at ``cost_target``.

    The penalty of ``shaped`` and ``checker`` is 0 for the first ``penalty_start`` fraction of
    the updates, then ramps linearly to ``penalty`` over the next ``penalty_warmup`` fraction;
    the Lagrangian multiplier stays at ``lagrangian_init`` until the ramp begins.

    ``novelty_bonus`` (0: off) adds an episodic exploration bonus to the training reward
    whenever a step reaches a (cell, carrying or not) pair not yet visited in the episode,
    annealed linearly to 0 over training. Evaluations, returns and success rates use the env
    reward only.

    The run is :attr:`num_chunks` chunks of ``eval_every`` updates of :attr:`batch_size`
    steps; ``total_timesteps`` is rounded down to whole chunks, and every schedule (learning
    rate, penalty ramp, novelty anneal) spans the :attr:`num_updates` updates actually run.
    ``conv_channels`` are the 3x3 convolutions of the policy's view encoder (``()``: an MLP
    over the FiLM-ed cell features). Why the defaults are what they are is recorded in
    ``docs/decisions.md``.
    """

    env_id: str = "TwoRooms-v0"
    env_kwargs: tuple[tuple[str, Any], ...] = ()
    num_envs: int = 256
    num_steps: int = 128
    total_timesteps: int = 2_000_000
    update_epochs: int = 4
    num_minibatches: int = 8
    lr: float = 1e-3
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    reward_mode: str = "none"
    penalty: float = 1.0
    penalty_start: float = 0.2
    penalty_warmup: float = 0.1
    checker_threshold: float = 0.5
    soft_checker: bool = False
    cost_target: float = 0.05
    lagrangian_lr: float = 0.05
    lagrangian_init: float = 0.0
    novelty_bonus: float = 0.0
    eval_every: int = 10
    eval_episodes: int = 50
    eval_seed: int = 20_200_207
    seed: int = 0
    conv_channels: tuple[int, ...] = (16,)

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
            "eval_every", "eval_episodes",
        )  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or value <= 0:
                raise ValueError(f"PPOConfig.{name} must be a positive integer, got {value!r}")
        for name in ("lr", "clip_eps", "max_grad_norm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"PPOConfig.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("gamma", "gae_lambda", "checker_threshold", "penalty_start", "penalty_warmup"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"PPOConfig.{name} must be in [0, 1], got {getattr(self, name)}")
        nonnegative = (
            "ent_coef",
            "vf_coef",
            "penalty",
            "cost_target",
            "lagrangian_lr",
            "lagrangian_init",
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
        if self.reward_mode not in REWARD_MODES:
            raise ValueError(
                f"PPOConfig.reward_mode must be one of {REWARD_MODES}, got {self.reward_mode!r}"
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
                f"updates of {self.batch_size} steps, fewer than eval_every ({self.eval_every})"
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
    def uses_checker(self) -> bool:
        return self.reward_mode in ("checker", "lagrangian")

    def make_env(self):
        return jaxgrid.make(self.env_id, **dict(self.env_kwargs))


def check_checker(config: PPOConfig, checker, env) -> None:
    """Fail fast, before any compile, when the checker does not fit the run."""
    if config.uses_checker and checker is None:
        raise ValueError(
            f"PPOConfig.reward_mode={config.reward_mode!r} needs a trained checker: pass "
            "checker=checker.load(DIR) (or train one with `python -m checker.train`)"
        )
    if checker is not None and checker.config.view_size != env.view_size:
        raise ValueError(
            f"checker view_size {checker.config.view_size} != env view_size {env.view_size}"
        )
