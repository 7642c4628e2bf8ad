"""Environment throughput on MiniGrid-DoorKey-8x8: jaxgrid vs NAVIX, XLand-MiniGrid, minigrid.

One thing, one benchmark's harness for four libraries and its report, hence its length.

Protocol: uniform random actions drawn inside the scan with ``jax.random``, auto-reset,
``jax.jit`` of a function that runs ``jax.lax.scan`` over T steps of ``jax.vmap(step)`` over N
envs. Every JAX library runs the identical harness (:func:`agents.timing.measure`):

* ``reset`` is vmapped over N keys once, outside the timed region;
* the jitted rollout is lowered and compiled explicitly; that wall time is the reported
  compile time (``compile_s``);
* the compiled rollout is then called ``repeats`` times on the same initial states, each
  call timed up to ``block_until_ready``; env steps/s = N * T / seconds. The headline
  number is the **best** of the repeats (least disturbed by other load); the median is
  reported alongside.

The rollout returns the summed reward, the number of finished episodes and a checksum
of the final observation, so XLA cannot dead-code-eliminate the observation computation.

Farama ``minigrid`` is plain Python: one env, a Python loop, ``reset`` on
terminated/truncated, random actions from NumPy. It is measured at N=1 only.

``jaxgrid-constrained`` is the same level with a constraint (``--constraint``, a budget on
DoorKey's yellow door by default; ``jaxgrid.make(id, constraint=...)``): the table then
gives its step time over the unconstrained one's, measured in the same run.

Usage::

    python -m benchmarks.env_throughput                      # defaults, ~2-3 min on 2 cores
    python -m benchmarks.env_throughput --num-envs 1 256 --libs jaxgrid xminigrid
    python -m benchmarks.env_throughput --json runs/env_throughput.json
    python -m benchmarks.env_throughput --libs jaxgrid jaxgrid-constrained --num-envs 4096

Quote ratios measured in one run, not absolute numbers (the machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import importlib
import importlib.metadata
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.timing import measure as measure_compiled
from benchmarks.cli import INSTALL, integer
from checker.cli import run_main
from jaxgrid.io import write_json

JAX_LIBS = ("jaxgrid", "navix", "xminigrid")
ALL_LIBS = (*JAX_LIBS, "minigrid")
#: The constrained level's variant, measured when asked (``--libs``), against ``jaxgrid``.
CONSTRAINED_LIB = "jaxgrid-constrained"
DEFAULT_CONSTRAINT = "do not use the yellow door more than twice"
DEFAULT_NUM_ENVS = (1, 256, 4096)
# Env steps per measurement (N * T) when --steps is not given: on a 2-core CPU the JAX
# peers run at ~1e4 (N=1) to ~5e5 steps/s, so one timed call takes about 0.1-2 s and the
# default run (9 compiles of 5-12 s each dominate) stays under ~3 minutes.
DEFAULT_STEP_BUDGET = {1: 8_192, 256: 262_144, 4096: 524_288}
DEFAULT_PYTHON_STEPS = 3_000
RESET_CHUNK = 256


@dataclasses.dataclass(frozen=True)
class Adapter:
    """A library's env behind one interface, so every library runs the same harness.

    ``env_state`` is whatever the library needs in the scan carry (its TimeStep, or
    jaxgrid's ``(state, timestep)``); all functions act on a single (unbatched) env.
    """

    lib: str
    env_id: str
    num_actions: int
    reset: Callable[[jax.Array], Any]
    step: Callable[[Any, jax.Array], Any]
    reward: Callable[[Any], jax.Array]
    done: Callable[[Any], jax.Array]
    observation: Callable[[Any], jax.Array]
    notes: dict[str, str]
    # A step of the whole batch, where the library has one (else ``vmap(step)``).
    batched_step: Callable[[Any, jax.Array], Any] | None = None


#: The level every peer ships, measured by default.
DEFAULT_ENV_ID = "MiniGrid-DoorKey-8x8-v0"


def _make_jaxgrid(env_id: str = DEFAULT_ENV_ID, constraint: str | None = None) -> Adapter:
    import jaxgrid

    given = {} if constraint is None else {"constraint": constraint}
    level = jaxgrid.make(env_id, **given)
    env = jaxgrid.wrappers.AutoReset(level)

    def step(env_state, action):
        state, _ = env_state
        return env.step(state, action)

    return Adapter(
        lib="jaxgrid",
        env_id=env_id,
        num_actions=int(getattr(env, "num_actions", 7)),
        reset=env.reset,
        step=step,
        reward=lambda s: s[1].reward,
        done=lambda s: jnp.logical_or(s[1].terminated, s[1].truncated),
        observation=lambda s: s[1].observation["image"],
        notes={
            "observation": "MiniGrid egocentric 7x7x3 uint8 image (with occlusion)",
            "auto_reset": "jaxgrid.wrappers.AutoReset (same-step reset, selected with jnp.where)",
            "actions": "uniform over the 7 MiniGrid actions",
            **({} if constraint is None else {"constraint": constraint}),
        },
    )


def _make_jaxgrid_constrained(
    env_id: str = DEFAULT_ENV_ID, constraint: str = DEFAULT_CONSTRAINT
) -> Adapter:
    """jaxgrid's level with a constraint (its monitor in the state, cost in the info)."""
    return dataclasses.replace(_make_jaxgrid(env_id, constraint), lib=CONSTRAINED_LIB)


def navix_id(env_id: str) -> str:
    """NAVIX's name for a MiniGrid id: ``MiniGrid-X`` is ``Navix-X``."""
    return "Navix-" + env_id.removeprefix("MiniGrid-")


def _make_navix(env_id: str = DEFAULT_ENV_ID) -> Adapter:
    import navix

    import jaxgrid

    max_steps = jaxgrid.make(env_id).max_steps  # MiniGrid's (navix.make defaults to 100)
    env_id = navix_id(env_id)
    if env_id not in navix.registry():
        raise ValueError(f"NAVIX has no {env_id}")
    env = navix.make(env_id, max_steps=max_steps)
    return Adapter(
        lib="navix",
        env_id=env_id,
        num_actions=len(env.action_set),
        reset=env.reset,
        step=env.step,
        reward=lambda ts: ts.reward,
        done=lambda ts: ts.is_done(),
        observation=lambda ts: ts.observation,
        notes={
            "observation": "default observations.symbolic: full 8x8x3 uint8 grid "
            "(fully observable, not egocentric, no occlusion)",
            "auto_reset": "built into Environment.step: lax.cond(step_type > 0, reset, _step), "
            "i.e. next-step (dm_env-style) reset; a select of both branches under vmap",
            "actions": "uniform over its 7 MiniGrid actions (MINIGRID_ACTION_SET)",
            "layout": "agent start fixed at (1,1) facing east (random_start=False), "
            "unlike MiniGrid; state carries an RGB RenderingCache",
            "max_steps": f"{max_steps} (MiniGrid's, passed explicitly; navix.make's is 100)",
        },
    )


def _make_xminigrid(env_id: str = DEFAULT_ENV_ID) -> Adapter:
    import xminigrid
    from xminigrid.wrappers import GymAutoResetWrapper

    env_id = env_id.removesuffix("-v0")
    if env_id not in xminigrid.registered_environments():
        raise ValueError(f"XLand-MiniGrid has no {env_id}")
    env, params = xminigrid.make(env_id)
    # The bare env does not auto-reset; the Gym-style wrapper resets on the same step,
    # which is what jaxgrid's AutoReset does.
    env = GymAutoResetWrapper(env)
    return Adapter(
        lib="xminigrid",
        env_id=env_id,
        num_actions=env.num_actions(params),
        reset=lambda key: env.reset(params, key),
        step=lambda ts, action: env.step(params, ts, action),
        reward=lambda ts: ts.reward,
        done=lambda ts: ts.last(),
        observation=lambda ts: ts.observation,
        notes={
            "observation": "default transparent_field_of_view: egocentric 7x7x2 uint8 "
            "(tile, colour), no occlusion",
            "auto_reset": "xminigrid.wrappers.GymAutoResetWrapper (same-step reset via "
            "lax.cond; a select of both branches under vmap); bare env does not reset",
            "actions": "uniform over its 6 actions (it has no 'done' action)",
            "max_steps": "its default (10 * h * w for DoorKey, as MiniGrid)",
        },
    )


def _make_jaxgrid_masked(env_id: str = DEFAULT_ENV_ID) -> Adapter:
    """jaxgrid stepped as its learner steps it: ``BatchedAutoReset`` generates fresh episodes
    only for the envs that ended (``AutoReset`` computes a reset for every env, every step)."""
    import jaxgrid

    batched = jaxgrid.wrappers.BatchedAutoReset(jaxgrid.make(env_id))
    single = _make_jaxgrid(env_id)
    return dataclasses.replace(
        single,
        lib="jaxgrid-masked",
        batched_step=lambda s, a: batched.step(s[0], a),
        notes={**single.notes, "auto_reset": "jaxgrid.wrappers.BatchedAutoReset (same-step "
               "reset, generated only where an episode ended: masked_map, 16 envs a pass)"},
    )  # fmt: skip


_ADAPTERS: dict[str, Callable[..., Adapter]] = {
    "jaxgrid": _make_jaxgrid,
    "jaxgrid-masked": _make_jaxgrid_masked,
    CONSTRAINED_LIB: _make_jaxgrid_constrained,
    "navix": _make_navix,
    "xminigrid": _make_xminigrid,
}


def make_rollout(adapter: Adapter, num_envs: int, steps: int) -> Callable:
    """Jittable rollout: ``lax.scan`` over ``steps`` of ``vmap(step)`` with random actions.

    The carry holds the batched env state and the action key. Returns the summed reward,
    the number of finished episodes and a checksum of the final observation (keeps the
    observation computation alive under XLA's dead-code elimination).
    """
    vstep = adapter.batched_step or jax.vmap(adapter.step)

    def body(carry, _):
        env_state, key, reward_sum, episodes = carry
        key, sub = jax.random.split(key)
        actions = jax.random.randint(sub, (num_envs,), 0, adapter.num_actions, dtype=jnp.int32)
        env_state = vstep(env_state, actions)
        reward_sum = reward_sum + jnp.sum(adapter.reward(env_state).astype(jnp.float32))
        episodes = episodes + jnp.sum(adapter.done(env_state).astype(jnp.int32))
        return (env_state, key, reward_sum, episodes), None

    def rollout(env_state, key):
        init = (env_state, key, jnp.float32(0.0), jnp.int32(0))
        (env_state, _, reward_sum, episodes), _ = jax.lax.scan(body, init, None, length=steps)
        obs_checksum = jnp.sum(adapter.observation(env_state).astype(jnp.int32))
        return reward_sum, episodes, obs_checksum

    return rollout


@functools.cache
def _adapter(lib: str, env_id: str = DEFAULT_ENV_ID, constraint: str | None = None) -> Adapter:
    """One adapter per library and level per process, so compiled resets are reused;
    ``constraint`` is the constrained variant's sentence (default :data:`DEFAULT_CONSTRAINT`)."""
    if lib == CONSTRAINED_LIB:
        return _ADAPTERS[lib](env_id, constraint or DEFAULT_CONSTRAINT)
    return _ADAPTERS[lib](env_id)


@functools.cache
def _jit_vreset(lib: str, env_id: str = DEFAULT_ENV_ID, constraint: str | None = None) -> Callable:
    return jax.jit(jax.vmap(_adapter(lib, env_id, constraint).reset))


def batched_reset(
    lib: str,
    key: jax.Array,
    num_envs: int,
    env_id: str = DEFAULT_ENV_ID,
    constraint: str | None = None,
) -> Any:
    """``vmap(reset)`` over ``num_envs`` keys, in fixed chunks of RESET_CHUNK envs.

    A fixed chunk shape compiles the reset once per library instead of once per N (the
    reset compile is several seconds on 2 cores and is not what is being measured).
    """
    vreset = _jit_vreset(lib, env_id, constraint)
    chunks = -(-num_envs // RESET_CHUNK)
    keys = jax.random.split(key, chunks * RESET_CHUNK)
    parts = [vreset(keys[i * RESET_CHUNK : (i + 1) * RESET_CHUNK]) for i in range(chunks)]
    if chunks == 1:
        return jax.tree.map(lambda x: x[:num_envs], parts[0])
    return jax.tree.map(lambda *xs: jnp.concatenate(xs)[:num_envs], *parts)


def _measure_jax(
    lib: str,
    num_envs: int,
    steps: int,
    repeats: int,
    seed: int,
    env_id: str = DEFAULT_ENV_ID,
    constraint: str | None = None,
) -> dict:
    adapter = _adapter(lib, env_id, constraint)
    key_reset, key_act = jax.random.split(jax.random.PRNGKey(seed))
    # Reset is not part of the measurement: done once, outside the timed region.
    t0 = time.perf_counter()
    env_state = jax.block_until_ready(batched_reset(lib, key_reset, num_envs, env_id, constraint))
    reset_s = time.perf_counter() - t0

    timing = measure_compiled(
        make_rollout(adapter, num_envs, steps), env_state, key_act, repeats=repeats
    )
    reward_sum, episodes, _ = timing.output
    env_steps = num_envs * steps
    return {
        "lib": lib,
        "env_id": adapter.env_id,
        "num_envs": num_envs,
        "steps": steps,
        "repeats": repeats,
        "compile_s": timing.compile_s,
        "reset_s": reset_s,
        "times_s": list(timing.times_s),
        "steps_per_s": env_steps / timing.best_s,
        "steps_per_s_median": timing.rate(env_steps),
        "episodes_finished": int(episodes),
        "reward_sum": float(reward_sum),
        "notes": adapter.notes,
    }


def _measure_minigrid(
    num_envs: int, steps: int, repeats: int, seed: int, env_id: str = DEFAULT_ENV_ID
) -> dict:
    import gymnasium as gym
    import minigrid  # noqa: F401  (registers the MiniGrid-* ids with gymnasium)

    if num_envs != 1:
        raise ValueError("minigrid is measured as a single Python env (num_envs=1)")
    env = gym.make(env_id)
    num_actions = int(env.action_space.n)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)

    times, episodes, reward_sum = [], 0, 0.0
    for _ in range(repeats):
        actions = rng.integers(0, num_actions, size=steps)
        t0 = time.perf_counter()
        for a in actions:
            _, reward, terminated, truncated, _ = env.step(int(a))
            reward_sum += reward
            if terminated or truncated:
                episodes += 1
                env.reset()
        times.append(time.perf_counter() - t0)
    env.close()
    return {
        "lib": "minigrid",
        "env_id": env_id,
        "num_envs": 1,
        "steps": steps,
        "repeats": repeats,
        "compile_s": None,
        "reset_s": None,
        "times_s": times,
        "steps_per_s": steps / min(times),
        "steps_per_s_median": steps / statistics.median(times),
        "episodes_finished": episodes,
        "reward_sum": reward_sum,
        "notes": {
            "observation": "dict obs; 'image' egocentric 7x7x3 uint8 with occlusion",
            "auto_reset": "env.reset() in the Python loop on terminated or truncated "
            "(inside the timed region)",
            "actions": f"uniform over its {num_actions} actions (NumPy)",
            "harness": "gymnasium.make with its default wrappers; plain Python, one env",
        },
    }


def measure(
    lib: str,
    num_envs: int,
    steps: int,
    repeats: int = 3,
    seed: int = 0,
    env_id: str = DEFAULT_ENV_ID,
    constraint: str | None = None,
) -> dict:
    """Measure one library at one batch size on ``env_id`` (a MiniGrid id; each library's
    own name for it); returns a JSON-serialisable result dict. ``constraint`` is
    ``jaxgrid-constrained``'s sentence (default :data:`DEFAULT_CONSTRAINT`).

    ``steps`` is T, the scan length (for ``minigrid``: the Python loop length per repeat).
    Keys include ``steps_per_s`` (best of ``repeats``), ``steps_per_s_median``,
    ``compile_s`` (lower + compile seconds; ``None`` for minigrid) and ``times_s``.
    """
    if lib == "minigrid":
        return _measure_minigrid(num_envs, steps, repeats, seed, env_id)
    if lib not in _ADAPTERS:
        raise ValueError(f"unknown lib {lib!r}; choose from {ALL_LIBS}")
    return _measure_jax(lib, num_envs, steps, repeats, seed, env_id, constraint)


def default_steps(num_envs: int) -> int:
    """T for a batch size when --steps is not given: about DEFAULT_STEP_BUDGET env steps."""
    budget = DEFAULT_STEP_BUDGET.get(num_envs, 524_288)
    return max(16, budget // num_envs)


_IMPORT_NAMES = {
    "jaxgrid": "jaxgrid",
    "jaxgrid-masked": "jaxgrid",
    CONSTRAINED_LIB: "jaxgrid",
    "navix": "navix",
    "xminigrid": "xminigrid",
    "minigrid": "minigrid",
}


def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        mod = sys.modules.get(dist)
        return getattr(mod, "__version__", None)


def check_import(lib: str) -> str | None:
    """Return None if ``lib`` (and what its adapter needs) imports, else the reason."""
    try:
        importlib.import_module(_IMPORT_NAMES[lib])
        if lib == "minigrid":
            importlib.import_module("gymnasium")
        elif lib == "jaxgrid":
            importlib.import_module("jaxgrid.wrappers")
    except Exception as exc:  # any import-time failure means "skipped", not a crash
        return f"{type(exc).__name__}: {exc}"
    return None


def machine_info() -> dict:
    """Where the numbers came from."""
    dev = jax.devices()[0]
    return {
        "processor": platform.processor(),
        "machine": platform.machine(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax_backend": jax.default_backend(),
        "device_kind": dev.device_kind,
        "num_devices": jax.device_count(),
    }


def library_versions() -> dict:
    """Versions of the measured libraries and of JAX itself."""
    names = ["jax", "jaxlib", "jaxgrid", "navix", "xminigrid", "minigrid", "gymnasium", "numpy"]
    out = {n: _version(n) for n in names}
    if out["jaxgrid"] is None:  # the project may be run from a checkout, not installed
        out["jaxgrid"] = getattr(sys.modules.get("jaxgrid"), "__version__", None)
    return out


def _fmt_rate(x: float | None) -> str:
    if x is None:
        return "-"
    if x >= 1e6:
        return f"{x / 1e6:.2f}M"
    if x >= 1e3:
        return f"{x / 1e3:.1f}k"
    return f"{x:.0f}"


def ratios(results: list[dict], num_envs: list[int]) -> dict[int, dict]:
    """jaxgrid steps/s over the faster of navix / xminigrid, per batch size."""
    best = {(r["lib"], r["num_envs"]): r["steps_per_s"] for r in results}
    out = {}
    for n in num_envs:
        ours = best.get(("jaxgrid", n))
        peers = {lib: best[(lib, n)] for lib in ("navix", "xminigrid") if (lib, n) in best}
        if ours is None or not peers:
            continue
        peer = max(peers, key=peers.get)
        out[n] = {"vs": peer, "ratio": ours / peers[peer]}
    return out


def constrained_ratios(results: list[dict], num_envs: list[int]) -> dict[int, float]:
    """Step time of the constrained level over the unconstrained one's, per batch size
    (unconstrained steps/s over constrained steps/s, both best of repeats, same run)."""
    best = {(r["lib"], r["num_envs"]): r["steps_per_s"] for r in results}
    return {
        n: best[("jaxgrid", n)] / best[(CONSTRAINED_LIB, n)]
        for n in num_envs
        if ("jaxgrid", n) in best and (CONSTRAINED_LIB, n) in best
    }


def format_table(
    results: list[dict], skipped: dict[str, str], num_envs: list[int], libs: list[str]
) -> str:
    """Readable table: rows = lib, columns = num envs (steps/s best-of, compile s)."""
    by = {(r["lib"], r["num_envs"]): r for r in results}
    width = max(10, *(len(lib) + 1 for lib in libs))
    columns = "".join(f"{f'N={n} steps/s':>18}{'compile s':>11}" for n in num_envs)
    head = f"{'lib':<{width}}" + columns
    lines = [
        "env steps/s (best of repeats) on MiniGrid-DoorKey-8x8, random actions, auto-reset",
        head,
        "-" * len(head),
    ]
    for lib in libs:
        if lib in skipped:
            lines.append(f"{lib:<{width}}  skipped: {skipped[lib]}")
            continue
        row = f"{lib:<{width}}"
        for n in num_envs:
            r = by.get((lib, n))
            rate = _fmt_rate(r["steps_per_s"]) if r else "-"
            comp = f"{r['compile_s']:.2f}" if r and r["compile_s"] is not None else "-"
            row += f"{rate:>18}{comp:>11}"
        lines.append(row)
    slower = constrained_ratios(results, num_envs)
    if slower:
        lines.append("")
        lines.append(
            "constrained step time / unconstrained: "
            + ", ".join(f"N={n}: {v:.2f}x" for n, v in slower.items())
        )
    rat = ratios(results, num_envs)
    if rat:
        lines.append("")
        lines.append(
            "jaxgrid / faster of navix, xminigrid: "
            + ", ".join(f"N={n}: {v['ratio']:.2f}x (vs {v['vs']})" for n, v in rat.items())
        )
    return "\n".join(lines)


def run(
    libs: list[str],
    num_envs: list[int],
    steps: int | None,
    repeats: int,
    python_steps: int,
    seed: int = 0,
    log: Callable[[str], None] = print,
    constraint: str = DEFAULT_CONSTRAINT,
) -> dict:
    """Run every (lib, N) measurement in one process and collect one report dict
    (``constraint``: the sentence of ``jaxgrid-constrained``)."""
    skipped: dict[str, str] = {}
    results: list[dict] = []
    for lib in libs:
        reason = check_import(lib)
        if reason is not None:
            skipped[lib] = reason
            log(f"[skip] {lib}: {reason} (to measure it: {INSTALL})")
            continue
        for n in num_envs:
            if lib == "minigrid" and n != 1:
                continue  # plain Python: a single env only
            t = python_steps if lib == "minigrid" else (steps or default_steps(n))
            log(f"[run] {lib:<9} N={n:<5} T={t:<6} ...")
            try:
                r = measure(lib, n, t, repeats, seed, constraint=constraint)
            except Exception as exc:  # report and go on; one broken peer must not hide others
                skipped.setdefault(lib, f"failed at N={n}: {type(exc).__name__}: {exc}")
                log(f"[fail] {lib} N={n}: {type(exc).__name__}: {exc}")
                break
            results.append(r)
            comp = "" if r["compile_s"] is None else f", compile {r['compile_s']:.2f} s"
            log(
                f"       {_fmt_rate(r['steps_per_s'])} steps/s{comp}, "
                f"episodes finished {r['episodes_finished']}"
            )
    return {
        "benchmark": "env_throughput",
        "env": "MiniGrid-DoorKey-8x8",
        "timestamp": datetime.datetime.now(datetime.timezone.utc).isoformat(),
        "protocol": {
            "actions": "uniform random, drawn inside the scan with jax.random",
            "harness": "jit(scan over T of vmap(step) over N envs); reset vmapped once "
            "outside the timed region; compile_s = lower()+compile() wall time; "
            "timed calls block_until_ready",
            "headline": "steps_per_s = N*T / best (minimum) time over repeats; "
            "steps_per_s_median also given",
            "minigrid": "single gymnasium env, Python loop, N=1 only",
        },
        "config": {
            "libs": libs,
            "num_envs": num_envs,
            "steps": steps,
            "default_steps": {n: default_steps(n) for n in num_envs},
            "python_steps": python_steps,
            "repeats": repeats,
            "seed": seed,
            "constraint": constraint,
        },
        "machine": machine_info(),
        "versions": library_versions(),
        "results": results,
        "skipped": skipped,
        "ratios_jaxgrid_vs_best_peer": {str(n): v for n, v in ratios(results, num_envs).items()},
        "constrained_step_time_ratio": {
            str(n): v for n, v in constrained_ratios(results, num_envs).items()
        },
    }


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.env_throughput",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument(
        "--num-envs",
        type=integer,
        nargs="+",
        default=list(DEFAULT_NUM_ENVS),
        help="batch sizes N to measure",
    )
    p.add_argument(
        "--steps",
        type=integer,
        default=None,
        help="scan length T for every N (None: T = budget / N, budgets "
        f"{DEFAULT_STEP_BUDGET} env steps)",
    )
    p.add_argument("--repeats", type=integer, default=3, help="timed calls per measurement")
    p.add_argument(
        "--libs",
        nargs="+",
        default=list(ALL_LIBS),
        choices=(*ALL_LIBS, CONSTRAINED_LIB),
        help="libraries to measure; a peer that does not import is skipped; "
        f"{CONSTRAINED_LIB}: jaxgrid's level with --constraint",
    )
    p.add_argument(
        "--constraint",
        default=DEFAULT_CONSTRAINT,
        help=f"the sentence of {CONSTRAINED_LIB} (a constraint DoorKey-8x8 can hold)",
    )
    p.add_argument(
        "--python-steps",
        type=integer,
        default=DEFAULT_PYTHON_STEPS,
        help="Python-loop steps per repeat for Farama minigrid",
    )
    p.add_argument("--seed", type=integer, default=0, help="seed of the resets and actions")
    p.add_argument("--json", metavar="PATH", default=None, help="also write the JSON here")
    return p  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    p = _parser()
    args = p.parse_args(argv)
    for name in ("repeats", "python_steps"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.steps is not None and args.steps < 1:
        p.error(f"--steps must be >= 1, got {args.steps}")
    if any(n < 1 for n in args.num_envs):
        p.error(f"--num-envs must all be >= 1, got {args.num_envs}")
    if args.seed < 0:  # MiniGrid's reset refuses it
        p.error(f"--seed must be >= 0, got {args.seed}")
    if CONSTRAINED_LIB in args.libs:  # a sentence DoorKey cannot hold: say so before compiling
        import jaxgrid

        try:
            jaxgrid.make(DEFAULT_ENV_ID, constraint=args.constraint)
        except ValueError as exc:
            p.error(f"--constraint: {exc}")
    missing = {lib: check_import(lib) for lib in args.libs}
    if all(missing.values()):  # nothing left to measure: say so now, not after the run
        raise ImportError(
            "none of --libs imports here ("
            + "; ".join(f"{lib}: {why}" for lib, why in missing.items())
            + f"); install the benchmarks' peers with: {INSTALL}"
        )

    report = run(
        args.libs,
        args.num_envs,
        args.steps,
        args.repeats,
        args.python_steps,
        args.seed,
        log=lambda s: print(s, file=sys.stderr, flush=True),
        constraint=args.constraint,
    )
    print(format_table(report["results"], report["skipped"], args.num_envs, args.libs))
    print()
    print(json.dumps(report, indent=2))
    if args.json:
        write_json(args.json, report)
    return report


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.env_throughput")
