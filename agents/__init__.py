"""PPO for language-constrained grid worlds, fused into one jitted update.

* :mod:`agents.config`: :class:`~agents.config.PPOConfig`, the frozen settings of a run;
* :mod:`agents.networks`: the actor-critic conditioned on the view and the sentence;
* :mod:`agents.rollout`: one env step with policy, checker, reward shaping and bootstrap;
* :mod:`agents.checker_carry`: the checker's per-env carry (any checker kind) that the
  rollout and the shield start and step;
* :mod:`agents.losses`: :func:`~agents.losses.gae`, :func:`~agents.losses.ppo_loss`;
* :mod:`agents.train`: ``make_train(config, checker) -> train(key)`` and the
  :class:`~agents.train.Learner` whose pieces it composes;
* :mod:`agents.runner`: seeds, sweeps, progress, logs, checkpoints and resume;
* :mod:`agents.checkpoint`: checkpoints, their digests, resume points and ``run.json``;
* :mod:`agents.programs`: the runner's compiled programs, kept and compiled ahead;
* :mod:`agents.devices`: the env batch split over devices and hosts;
* :mod:`agents.evaluation`: fixed-seed evaluation episodes;
* :mod:`agents.baseline`: the PureJaxRL-style PPO, the reference of our PPO's speed and
  this machine's baseline figure (timed by :mod:`agents.timing`).

``agents`` imports ``checker`` and ``jaxgrid``, never ``experiments``.
"""
