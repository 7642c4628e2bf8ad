"""HazardRooms: constraints that count, wait for a trigger or keep a distance.

Run ``python -m experiments.hazard_rooms [--quick | --paper] [--out DIR]``.

The agents' episodes draw one of :data:`SENTENCES`, one or two of each constraint type of
:mod:`jaxgrid.language` (the learner encodes a fixed table of sentences). The checker
is the memory checker (:mod:`checker.memory_model`, phases in :mod:`experiments.memory_phase`),
and the policy is recurrent (``PPOConfig(recurrent=True)``), so that both can count. The
episodic novelty bonus is 0.05 instead of the paper scenarios' 0.01: behind two closed doors
the goal is too rare a find for a learner that is also penalised. It is capped at 60 bonuses
an episode, and the goal pays those not yet earned (``novelty_claim``), so that touring the
rooms never pays more than the goal, and it pays for new cells, not new (cell, carrying)
pairs (``novelty_carrying=False``): with the key in hand the first room would pay twice, and
agents stayed in it (``docs/decisions.md``). The memory checker labels each
frame with the violation of the step into it (``lookahead=0``), not of the step out of it:
a frame and the episode's memory determine the former, while the latter also depends on the
action not yet taken, and a shield asks about the frame each candidate action leads to.
The shield has a memory checker of its own (``shield_guided=0.5``): half of its streams'
actions come from the BFS oracle, so they pass the doors and reach the goal as trained
agents do. With the random streams' checker the shield's false alarms inside whole episodes
cost it a tenth of its successes; with this one it blocks far less, while the checker-shaped
agents keep the random streams' checker, whose budget violations, more numerous there, hold
their violations lower (``docs/decisions.md``). Film codes and ``alarm_forward``, on in the
paper scenarios, are off: they were measured on those scenarios' window checker, not on this
one's memory checker. Every other setting, the outputs and the statistics are those of
:mod:`experiments.pipeline`; ``--help`` lists the flags.
"""

from checker.cli import run_main
from experiments.pipeline import main, override, scenario

# One or two sentences of each type; budgets and the trigger concern hazards across the routes.
SENTENCES = (
    "avoid lava",
    "do not step on lava more than twice",
    "after you pick up the key, do not use the red door",
    "never stand next to lava",
    "stay away from water and use the red door at most once",
)

SCENARIO = override(
    scenario("hazard_rooms", "HazardRooms-v0"),
    dict(checker_kind="memory", memory_checker=dict(lookahead=0), shield_guided=0.5,
         ppo=dict(env_kwargs=(("sentences", SENTENCES),), recurrent=True,
                  novelty_bonus=0.05, novelty_claim=60, novelty_carrying=False,
                  film_codes=False, alarm_forward=False)),
)  # fmt: skip

if __name__ == "__main__":
    run_main(lambda: main(SCENARIO), "python -m experiments.hazard_rooms")
