"""The compiled programs of :func:`agents.runner.run`, kept per process between calls.

A run's programs depend on its configuration, checker, devices and swept names, not on its
seeds' values or its directory: :func:`programs_for` builds them once per combination, and
:func:`precompile` compiles them ahead of time, in another thread if need be (XLA's compiler
releases the GIL), so that a run spends no time compiling. Same numbers either way.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from agents import checkpoint, devices
from agents.config import PPOConfig, check_sweep
from agents.evaluation import summarise
from agents.train import make_learner

__all__ = ["Programs", "precompile", "programs_for"]


def _finite(tree) -> jax.Array:
    """Whether every floating-point leaf of ``tree`` is finite (one traced bool)."""
    leaves = [
        jnp.all(jnp.isfinite(x))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(x.dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(leaves))


class Programs:
    """The jitted pieces of ``run`` for one (config, checker, devices, swept names)
    combination: ``init`` (keys, hparams -> runner state), ``chunk`` (runner state ->
    runner state, metrics, finite flags; one chunk of ``eval_every`` updates) and
    :meth:`final` (the final evaluation), all vmapped over agents, with the ``learner``,
    ``mesh`` and runner-state ``shardings`` they were built for.

    :meth:`warm` compiles them ahead of time for a number of agents (:func:`precompile`);
    :meth:`executable` hands out what it compiled.
    """

    def __init__(self, config: PPOConfig, checker, multi_host: bool, swept: tuple = ()):
        learner = make_learner(config, checker)
        mesh = devices.mesh(config.num_envs, multi_host)
        hparams = {n: jnp.zeros((1,), jnp.float32) for n in swept}
        abstract = jax.eval_shape(jax.vmap(learner.init), jax.random.PRNGKey(0)[None], hparams)
        # Explicit shardings on one device too: the arrays orbax restores are committed to
        # a device, the output of a jit without out_shardings is not, and jit would compile
        # the chunk again for the resumed (committed) runner state.
        one = Mesh(np.asarray(devices.devices(multi_host)[:1]), ("envs",))
        shardings = devices.shardings(abstract, mesh if mesh is not None else one)

        def chunk_fn(runner):
            runner, metrics = jax.vmap(learner.chunk)(runner)
            finite = jax.vmap(lambda r, m: _finite((r.params, m["train"]["loss"])))(runner, metrics)
            return runner, metrics, finite

        self.checker = checker  # keeps id(checker) of the cache key alive
        self.swept = swept
        self.learner, self.mesh, self.shardings = learner, mesh, shardings
        self.init = jax.jit(jax.vmap(learner.init), out_shardings=shardings)
        self.chunk = jax.jit(
            chunk_fn, in_shardings=(shardings,), out_shardings=(shardings, None, None)
        )
        self._final: dict[int, Any] = {}
        self._ready: dict[tuple, Any] = {}  # (name, agents, ...) -> compiled executable
        self._warming = threading.Lock()  # held while warm() compiles

    def final(self, num_episodes: int):
        """The jitted final evaluation over ``num_episodes`` fixed-seed episodes (params,
        hparams -> summary per agent; in the shield modes also ``"unshielded"``)."""
        if num_episodes not in self._final:
            config, learner = self.learner.config, self.learner
            key = jax.random.PRNGKey(config.eval_seed + 1)

            def final(params, hparams):
                out = summarise(learner.evaluate(params, key, num_episodes, hparams=hparams))
                if learner.shield is not None:  # the policy alone, too
                    off = learner.evaluate(params, key, num_episodes, shielded=False)
                    out["unshielded"] = summarise(off)
                return out

            self._final[num_episodes] = jax.jit(jax.vmap(final))
        return self._final[num_episodes]

    def warm(self, agents: int, final_episodes: int = 0, train: bool = True) -> None:
        """Compile ``init`` and ``chunk`` (if ``train``) and, if ``final_episodes``,
        ``final`` for ``agents``."""
        with self._warming:
            key = jax.eval_shape(lambda: jax.random.PRNGKey(0))
            keys = jax.ShapeDtypeStruct((agents, *key.shape), key.dtype)
            hparams = {n: jax.ShapeDtypeStruct((agents,), jnp.float32) for n in self.swept}
            abstract = jax.eval_shape(jax.vmap(self.learner.init), keys, hparams)
            lowerings = {}
            if train:
                lowerings["init", agents] = lambda: self.init.lower(keys, hparams)
                lowerings["chunk", agents] = lambda: self.chunk.lower(abstract)
            if final_episodes:
                final = self.final(final_episodes)
                lowerings["final", agents, final_episodes] = lambda: final.lower(
                    abstract.params, abstract.hparams
                )
            for name, lower in lowerings.items():  # each program once, whoever asked first
                if name not in self._ready:
                    self._ready[name] = lower().compile()

    def executable(self, name: str, agents: int, *args):
        """The compiled ``name`` program for ``agents`` if :meth:`warm` made it (waiting for
        a warm in progress), else the jitted function, which compiles on its first call."""
        with self._warming:
            ready = self._ready.get((name, agents, *args))
        if ready is not None:
            return ready
        if name == "final":
            return self.final(*args)
        return {"init": self.init, "chunk": self.chunk}[name]


_PROGRAMS: OrderedDict = OrderedDict()
_MAX_PROGRAMS = 8  # an experiment's behaviour agent and its six reward modes
_PROGRAMS_LOCK = threading.Lock()  # precompile() may run in another thread


def programs_for(
    config: PPOConfig, checker=None, multi_host: bool = False, swept: tuple = ()
) -> Programs:
    """The :class:`Programs` of a run, built on first use and kept per process (the eight
    last used), so that calling ``run`` again with the same
    configuration, e.g. to resume, to add seeds or from a sweep, compiles nothing.
    ``swept``: the names a sweep varies (their values are arguments of the programs)."""
    used = devices.devices(multi_host)
    key = (config, None if checker is None else id(checker), tuple(d.id for d in used), swept)
    with _PROGRAMS_LOCK:
        if key in _PROGRAMS:
            _PROGRAMS.move_to_end(key)  # config and checker were validated when it was built
            return _PROGRAMS[key]
        programs = Programs(config, checker, multi_host, swept)
        _PROGRAMS[key] = programs
        while len(_PROGRAMS) > _MAX_PROGRAMS:
            _PROGRAMS.popitem(last=False)
        return programs


def precompile(
    config: PPOConfig,
    checker=None,
    *,
    seeds: Sequence[int] = (0,),
    final_episodes: int = 0,
    multi_host: bool = False,
    sweep: Mapping[str, Sequence[float]] | None = None,
    out_dir: str | os.PathLike | None = None,
) -> None:
    """Compile the programs of :func:`agents.runner.run` with these arguments (its keywords),
    so that ``run`` spends no time compiling. Thread-safe: XLA's compiler releases the GIL,
    so a thread can compile one run's programs while another run trains
    (``experiments.pipeline`` does); a ``run`` that needs programs still compiling here waits
    for them. Same results as without it.
    Where ``out_dir`` already records a checkpoint of the last chunk, only the final
    evaluation compiles: resuming a finished run trains nothing.
    """
    sweep = check_sweep(sweep, config)
    agents = len(seeds) * int(np.prod([len(v) for v in sweep.values()]))
    train = out_dir is None or not checkpoint.finished(Path(out_dir), config)
    programs_for(config, checker, multi_host, tuple(sweep)).warm(agents, final_episodes, train)
