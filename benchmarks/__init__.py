"""Throughput benchmarks: environments (``env_throughput``), PPO training (``train_speed``
against the PureJaxRL-style baseline ``purejaxrl_ppo``), and their shared timing protocol
(``timing``)."""
