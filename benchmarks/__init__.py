"""Throughput benchmarks: environments (``env_throughput``), PPO training (``train_speed``
against the PureJaxRL-style baseline ``purejaxrl_ppo``), and their shared timing protocol
(``timing``)."""

from jaxgrid.rundir import interruptible_if_command

interruptible_if_command()  # `python -m benchmarks...`: Ctrl-C handled before jax loads
