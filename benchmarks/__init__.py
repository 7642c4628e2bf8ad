"""Throughput benchmarks: environments (``env_throughput``), PPO training (``train_speed``
against the PureJaxRL-style baseline, :mod:`agents.baseline`, also timed alone by
``purejaxrl_ppo``), all with one timing protocol (:mod:`agents.timing`)."""

from jaxgrid.rundir import interruptible_if_command

interruptible_if_command()  # `python -m benchmarks...`: Ctrl-C handled before jax loads
