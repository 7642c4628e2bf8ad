"""The paper-reproduction experiments (``python -m experiments.<name>``)."""

from jaxgrid.rundir import prepare_command

prepare_command()  # `python -m experiments...`: Ctrl-C and a held --out handled before jax loads
