"""``run.json`` beside a run's checkpoints: what a resume must match.

It holds the :class:`~agents.config.PPOConfig` (less its seed), the seeds of every agent, the
checker's parameter digest and any sweep (:func:`write_run_info`); :func:`check_run_info`
refuses a resume that differs from it, :func:`read_run_info` and :func:`saved_config` read
its configuration back (settings renamed since under today's names).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax

from agents.checkpoint import ResumeError
from agents.config import PPOConfig, renamed
from jaxgrid import io, rundir

__all__ = ["RUN_INFO", "check_run_info", "checker_sha256", "read_run_info", "run_info",
           "saved_config", "write_run_info"]  # fmt: skip

RUN_INFO = "run.json"


def checker_sha256(checker) -> str | None:
    """Identifies the checker's parameters (``None`` without a checker), so that a resume or
    a load with another checker is refused."""
    if checker is None:
        return None
    from flax import serialization

    return rundir.sha256_bytes(serialization.to_bytes(jax.device_get(checker.params)))


def run_info(config: PPOConfig, seeds: list[int], checker=None,
             sweep: Mapping[str, Sequence[float]] | None = None) -> dict:  # fmt: skip
    """What ``run.json`` holds for a run: ``config`` (its fields less ``seed``, as JSON),
    ``seeds`` (one per agent), ``checker_sha256`` and, only with a sweep, ``sweep``."""
    fields = {k: v for k, v in dataclasses.asdict(config).items() if k != "seed"}
    info = {"config": fields, "seeds": seeds, "checker_sha256": checker_sha256(checker)}
    if sweep:  # absent without a sweep: run.json as before
        info["sweep"] = {n: [float(v) for v in values] for n, values in sweep.items()}
    return json.loads(json.dumps(info, default=repr))


def write_run_info(out: Path, config: PPOConfig, seeds: list[int], checker=None,
                   sweep: Mapping[str, Sequence[float]] | None = None) -> None:  # fmt: skip
    """Write :func:`run_info` to ``out/run.json``."""
    io.write_json(out / RUN_INFO, run_info(config, seeds, checker, sweep))


def check_run_info(out: Path, config: PPOConfig, seeds: list[int], checker=None,
                   sweep: Mapping[str, Sequence[float]] | None = None) -> None:  # fmt: skip
    """Refuse to resume a run made with another configuration, sweep or other seeds
    (``ValueError``) and a damaged, missing or other checker's ``run.json``
    (:class:`ResumeError`). A config field missing from the file (written before the field
    existed) matches while ``config`` holds the field's declared default."""
    path = out / RUN_INFO
    start_over = "delete it to start over"
    try:
        saved = _upgraded(io.read_json(path))
        saved["seeds"]
    except FileNotFoundError:
        raise ResumeError(f"{path}: missing, so the checkpoints in {out / 'checkpoints'} cannot "
                          f"be matched to a configuration; {start_over}") from None  # fmt: skip
    except (ValueError, TypeError, KeyError) as e:
        raise ResumeError(f"{path}: damaged ({e}); {start_over}") from None
    now = run_info(config, seeds, checker, sweep)
    if saved.get("checker_sha256") != now["checker_sha256"]:
        raise ResumeError(f"{path}: the run in {out} was made with another checker; "
                          f"{start_over}")  # fmt: skip
    if saved.get("sweep") != now.get("sweep"):
        raise ValueError(
            f"cannot resume {out}: it was run with sweep {saved.get('sweep')}, not "
            f"{now.get('sweep')} (pass resume=False to start over, or another out_dir)"
        )
    if saved["seeds"] != now["seeds"]:
        raise ValueError(
            f"cannot resume {out}: it was run with seeds {saved['seeds']}, not {seeds} "
            "(pass resume=False to start over, or another out_dir)"
        )
    diff = sorted(
        k for k in set(saved["config"]) | set(now["config"])
        if saved["config"].get(k) != now["config"].get(k)
        and not (k not in saved["config"] and io.holds_declared_default(config, k))
    )  # fmt: skip
    if diff:
        raise ValueError(
            f"cannot resume {out}: PPOConfig differs in {diff} (saved "
            f"{ {k: saved['config'].get(k) for k in diff} }); pass resume=False to start "
            "over, or another out_dir"
        )


def read_run_info(out: Path) -> dict:
    """``out/run.json`` as :func:`write_run_info` wrote it; a ``ValueError`` naming the
    directory if there is none (no run there) or the file if it is damaged."""
    try:
        info = _upgraded(io.read_json(out / RUN_INFO))
    except FileNotFoundError:
        raise ValueError(f"{out}: no run.json, so no run of agents.runner.run") from None
    except (ValueError, TypeError, KeyError) as e:
        raise ValueError(f"{out / RUN_INFO}: damaged ({e})") from None
    return info


def _upgraded(info: dict) -> dict:
    """A ``run.json`` record with the settings of its config and sweep under today's names
    (:data:`agents.config.RENAMED`); a ``KeyError`` or ``TypeError`` if it has no config."""
    if not isinstance(info["config"], dict):
        raise TypeError(f"its config is {type(info['config']).__name__}, not an object")
    info = {**info, "config": renamed(info["config"])}
    if info.get("sweep") is not None:
        info["sweep"] = renamed(info["sweep"])
    return info


def saved_config(info: dict) -> PPOConfig:
    """The :class:`PPOConfig` of a :func:`read_run_info` record (JSON lists back to the
    config's tuples; fields this code no longer knows are dropped)."""

    def tuples(x):
        return tuple(map(tuples, x)) if isinstance(x, list) else x

    known = {f.name for f in dataclasses.fields(PPOConfig)}
    return PPOConfig(**{k: tuples(v) for k, v in info["config"].items() if k in known})
