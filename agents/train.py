from agents.ppo import Learner, RunnerState, evaluation_steps, make_learner, make_train  # noqa: F401
