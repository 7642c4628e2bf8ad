"""``python -m benchmarks.purejaxrl_ppo``: bad flags and envs are usage errors before any
compile (the learner it times is tested in ``tests/agents/test_baseline.py``)."""

import pytest

from benchmarks import purejaxrl_ppo as bench


@pytest.mark.parametrize(
    "argv, flag",
    [(["--timesteps", "100"], "--timesteps"), (["--num-minibatches", "3"], "--num-minibatches"),
     (["--num-envs", "0"], "--num-envs"), (["--update-epochs", "x"], "--update-epochs")],
)  # fmt: skip
def test_cli_rejects_bad_flags_before_compiling(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(argv)
    assert exc.value.code == 2 and flag in capsys.readouterr().err


def test_an_unknown_env_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        bench.main(["--env", "MiniGrid-Nope-v0"])
    assert "--env 'MiniGrid-Nope-v0'" in capsys.readouterr().err
