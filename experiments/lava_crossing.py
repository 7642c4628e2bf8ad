"""LavaCrossing with a lava budget: a MiniGrid level with a constraint that counts.

Run ``python -m experiments.lava_crossing [--quick | --paper] [--out DIR]``: the row
``EXPERIMENTS["lava_crossing"]`` of :mod:`experiments.presets` (``MiniGrid-LavaCrossingS9N1-v0``
with lava that costs and "do not step on lava more than twice", a memory checker and a
recurrent policy), by :func:`experiments.pipeline.main`; ``--help`` lists the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main
from experiments.presets import EXPERIMENTS

SCENARIO = EXPERIMENTS["lava_crossing"]

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.lava_crossing")
