"""The paper-reproduction experiments (``python -m experiments.<name>``)."""

from jaxgrid.rundir import interruptible_if_command

interruptible_if_command()  # `python -m experiments...`: Ctrl-C handled before jax loads
