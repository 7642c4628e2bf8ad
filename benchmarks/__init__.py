"""Throughput benchmarks: environments (``env_throughput``), PPO training (``train_speed``
against the PureJaxRL-style baseline, :mod:`agents.baseline`, also timed alone by
``purejaxrl_ppo``), all with one timing protocol (:mod:`agents.timing`)."""

from jaxgrid.rundir import prepare_command

prepare_command()  # `python -m benchmarks...`: Ctrl-C and a held --out handled before jax loads
