"""``agents.config``: every bad setting raises a ``ValueError`` naming its field, on
construction; and a bad env setting or checker fails before anything is compiled, in
``make_learner``, ``make_train`` and ``run`` alike."""

from __future__ import annotations

import dataclasses

import pytest
from helpers.agents_cases import (
    CHECKER_CONFIG,
    TINY,
    assert_counter_sees_compiles,
    count_compiles,
)

from agents.runner import run
from agents.train import make_learner, make_train
from checker.model import TrainedChecker


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(num_envs=0), "num_envs"),
        (dict(num_steps=-1), "num_steps"),
        (dict(total_timesteps=0), "total_timesteps"),
        (dict(update_epochs=0), "update_epochs"),
        (dict(num_minibatches=0), "num_minibatches"),
        (dict(eval_every=0), "eval_every"),
        (dict(eval_episodes=0), "eval_episodes"),
        (dict(num_envs=2.5), "num_envs"),
        (dict(num_minibatches=3), "num_minibatches"),  # 64 steps per update
        (dict(num_envs=6, num_steps=4, num_minibatches=4), "num_minibatches"),
        (dict(total_timesteps=8 * 8), "total_timesteps"),  # 1 update < eval_every
        (dict(reward_mode="penalty"), "reward_mode"),
        (dict(gamma=1.5), "gamma"),
        (dict(gamma=-0.1), "gamma"),
        (dict(gae_lambda=1.01), "gae_lambda"),
        (dict(lr=0.0), "lr"),
        (dict(lr=float("nan")), "lr"),
        (dict(clip_eps=-0.2), "clip_eps"),
        (dict(checker_threshold=2.0), "checker_threshold"),
        (dict(penalty=-1.0), "penalty"),
        (dict(lagrangian_init=-1.0), "lagrangian_init"),
        (dict(conv_channels=(16, 0)), "conv_channels"),
        (dict(conv_channels=16), "conv_channels"),
        (dict(env_kwargs=(("max_steps", [3]),)), "env_kwargs"),
        (dict(cost_limit=-0.1), "cost_limit"),
        (dict(pid_kp=-1.0), "pid_kp"),
        (dict(saute_penalty=-1.0), "saute_penalty"),
        (dict(focops_lam=0.0), "focops_lam"),
        (dict(focops_max_kl=0.0), "focops_max_kl"),
        (dict(focops_nu_max=-1.0), "focops_nu_max"),
        (dict(cpo_max_kl=0.0), "cpo_max_kl"),
        (dict(cpo_cg_iters=0), "cpo_cg_iters"),
        (dict(cpo_damping=-0.1), "cpo_damping"),
        (dict(cpo_fisher_every=0), "cpo_fisher_every"),
        (dict(reward_mode="lagrangian", cost_source="oracle"), "cost_source"),
        # a cost source the mode cannot use: its own is fixed, or it has no cost
        (dict(reward_mode="shield_monitor", cost_source="checker"), "cost_source='checker'"),
        (dict(reward_mode="shield", cost_source="monitor"), "cost_source='monitor'"),
        (dict(reward_mode="shaped", cost_source="checker"), "cost_source='checker'"),
        (dict(reward_mode="checker", cost_source="monitor"), "cost_source='monitor'"),
        (dict(reward_mode="none", cost_source="monitor"), "has no cost"),
    ],
)
def test_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(TINY, **kwargs)


def test_each_mode_takes_its_cost_from_its_own_source_unless_told():
    """``cost_source`` None is the mode's own source; a constrained mode takes either."""
    own = {"checker": "checker", "shaped": "monitor", "none": None, "lagrangian": "checker",
           "shield": "checker", "shield_monitor": "monitor"}  # fmt: skip
    for mode, source in own.items():
        config = dataclasses.replace(TINY, reward_mode=mode)
        assert config.cost_from == source and config.uses_checker == (source == "checker")
        assert config.shield_judge == (source if mode.startswith("shield") else None)
    monitored = dataclasses.replace(TINY, reward_mode="lagrangian", cost_source="monitor")
    assert monitored.cost_from == "monitor" and not monitored.uses_checker
    assert make_learner(monitored).checker is None  # no checker needed, none kept


def test_config_accepts_edges_and_normalises_env_kwargs():
    assert dataclasses.replace(TINY, gamma=0.0, gae_lambda=1.0).gamma == 0.0
    a = dataclasses.replace(TINY, env_kwargs={"max_steps": 4, "view_size": 5})
    b = dataclasses.replace(TINY, env_kwargs=(("view_size", 5), ("max_steps", 4)))
    assert a == b and hash(a) == hash(b)
    assert a.make_env().max_steps == 4


def test_bad_env_and_checker_fail_before_compiling():
    """No XLA compilation at all (counted through ``jax.monitoring``) before the error."""
    wide = TrainedChecker(params={}, config=dataclasses.replace(CHECKER_CONFIG, view_size=7))
    with count_compiles() as compiled:
        for mode in ("checker", "lagrangian", "pid_lagrangian", "saute", "focops", "cpo"):
            config = dataclasses.replace(TINY, reward_mode=mode)
            for build in (make_learner, make_train):
                with pytest.raises(ValueError, match="reward_mode='" + mode):
                    build(config)
            with pytest.raises(ValueError, match="needs a trained checker"):
                run(config, progress=False)
        with pytest.raises(ValueError, match="no setting 'max_stepz'"):
            make_learner(dataclasses.replace(TINY, env_kwargs=(("max_stepz", 3),)))
        with pytest.raises(ValueError, match="view_size"):
            make_learner(dataclasses.replace(TINY, reward_mode="checker"), wide)
        with pytest.raises(ValueError, match="distinct"):
            run(TINY, seeds=(1, 1), progress=False)
    assert compiled == []
    assert_counter_sees_compiles()
