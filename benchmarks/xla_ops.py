"""Which compiled XLA operations the time of a jitted function goes to, from a profiler trace.

``train_speed --ops N`` uses this to say where one PPO update spends its time, op by op.
:func:`profile_ops` runs an ahead-compiled executable a few times under
``jax.profiler.trace``, reads back the Chrome-format trace (``*.trace.json.gz``) that JAX
writes, and sums the duration of each of the executable's HLO instructions. The
instruction's ``op_name`` metadata says where it came from: Flax names its modules
(``flax_profile``, on by default), so a line reads e.g. ``backward: ActorCritic/cells``.

How to read the figures: XLA:CPU runs each fused kernel as one "thunk" and the trace holds
one event per thunk run, so the figures are the kernels' own times, summed over every loop
iteration; time spent between kernels (loop bookkeeping, thread hand-offs) is in no line,
and the shares are of the traced kernels' total. Tracing adds a little time to every kernel
run, so small kernels run many times (a rollout's per-step ops, loops) read larger than
their share of an untraced run: rank with this, time with ``--profile``. On another backend
the event names may not match the instruction names; then nothing is found and
:func:`profile_ops` says so.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import os
import re
import tempfile
from collections.abc import Callable

import jax

_INSTRUCTION = re.compile(r'^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=.*?op_name="([^"]*)"', re.MULTILINE)
# Name-stack parts that say nothing about the model: loop and call plumbing.
_PLUMBING = re.compile(r"^(?:while|body|cond|closed_call|checkpoint|all)$")


def instruction_sources(hlo_text: str) -> dict[str, str]:
    """``{instruction name: op_name metadata}`` of an optimised HLO module's text."""
    return dict(_INSTRUCTION.findall(hlo_text))


def describe(op_name: str) -> str:
    """Where an ``op_name`` comes from, coarsely: the pass (``loss forward``, ``backward``,
    or ``outside the loss``: rollout, GAE, shuffling, optimiser) and the Flax modules (or,
    outside any module, the jitted JAX function) it ran in; loop plumbing and the primitive
    itself are dropped.

    ``jit(run)/while/body/closed_call/transpose(jvp(ActorCritic))/cells/dot_general`` ->
    ``backward: ActorCritic/cells``.
    """
    parts = op_name.split("/")[1:-1]  # drop the outer jit(...) and the primitive
    phase = "outside the loss"
    if any(p.startswith("transpose(jvp") for p in parts):
        phase = "backward"
    elif any(p.startswith("jvp(") for p in parts):
        phase = "loss forward"
    modules, functions = [], []
    for p in parts:
        if _PLUMBING.match(p):
            continue
        if p.startswith("jit("):  # a jitted helper: jit(argsort), jit(relu)
            functions.append(p[4:].rstrip(")"))
            continue
        inner = re.sub(r"^(?:transpose\()?(?:jvp\()?([^()]*)\)*$", r"\1", p)
        if inner:
            modules.append(inner)
    where = "/".join(modules) or "/".join(functions) or "(no module)"
    return f"{phase}: {where}"


def _read_trace(directory: str) -> list[dict]:
    files = glob.glob(os.path.join(directory, "**", "*.trace.json.gz"), recursive=True)
    if not files:
        raise RuntimeError(f"jax.profiler wrote no *.trace.json.gz under {directory}")
    with gzip.open(max(files, key=os.path.getmtime)) as f:
        return json.load(f).get("traceEvents", [])


def profile_ops(
    run: Callable[[], object], hlo_text: str, calls: int, per_call: int, top: int = 15
) -> dict:
    """Time ``run()`` (one call of an executable whose optimised HLO is ``hlo_text``)
    ``calls`` times under the profiler; ``per_call`` units (updates) per call.

    Returns ``{"traced_ms_per_unit", "ops": [...], "groups": [...]}``: the ``top``
    instructions and the ``top`` places (:func:`describe`, instructions summed) by time,
    each with ``ms_per_unit`` and ``share`` of the traced total. ``run`` must block until
    its result is ready. Raises ``RuntimeError`` if the trace holds none of the
    instructions.
    """
    if calls < 1 or per_call < 1 or top < 1:
        raise ValueError(f"calls, per_call and top must be >= 1, got {calls}, {per_call}, {top}")
    sources = instruction_sources(hlo_text)
    run()  # warm: the first call may allocate or load
    with tempfile.TemporaryDirectory(prefix="xla_ops_") as directory:
        jax.profiler.start_trace(directory)
        try:
            for _ in range(calls):
                run()
        finally:
            jax.profiler.stop_trace()
        events = _read_trace(directory)
    micros = collections.Counter()
    for e in events:
        if e.get("ph") == "X" and e.get("name") in sources:
            micros[e["name"]] += float(e.get("dur", 0.0))
    total = sum(micros.values())
    if total <= 0:
        raise RuntimeError(
            "the profiler trace names none of the executable's HLO instructions "
            f"({len(events)} events; backend {jax.default_backend()})"
        )
    units = calls * per_call

    def row(key, us):
        return {"ms_per_unit": round(us / 1e3 / units, 3), "share": round(us / total, 4), **key}

    groups = collections.Counter()
    for name, us in micros.items():
        groups[describe(sources[name])] += us
    return {
        "traced_ms_per_unit": round(total / 1e3 / units, 2),
        "ops": [
            row({"op": n, "where": describe(sources[n])}, us) for n, us in micros.most_common(top)
        ],
        "groups": [row({"where": w}, us) for w, us in groups.most_common(top)],
    }
