"""PPO for language-constrained grid worlds, fused into one jitted update.

* :mod:`agents.config`: :class:`~agents.config.PPOConfig`, the frozen settings of a run;
* :mod:`agents.networks`: the actor-critic conditioned on the view and the sentence;
* :mod:`agents.rollout`: one env step with policy, checker, reward shaping and bootstrap;
* :mod:`agents.checker_carry`: the checker's per-env carry (any checker kind) that the
  rollout and the shield start and step;
* :mod:`agents.losses`: :func:`~agents.losses.gae`, :func:`~agents.losses.ppo_loss`;
* :mod:`agents.train`: ``make_train(config, checker) -> train(key)`` and the
  :class:`~agents.train.Learner` whose pieces it composes;
* :mod:`agents.runner`: seeds, devices, progress, logs, checkpoints and resume;
* :mod:`agents.evaluation`: fixed-seed evaluation episodes.

``agents`` imports ``checker`` and ``jaxgrid``, never ``experiments``.
"""
