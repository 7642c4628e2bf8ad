"""The saved state of :func:`agents.runner.run`'s ``out_dir``: orbax checkpoints that cannot
collide and resume only from state whose files and logged records match recorded sha256
digests (``run.json``, which names the configuration, seeds and checker a resume must match,
is :mod:`agents.run_record`'s).

- **One save at a time per process.** orbax pairs the background writes of a save with the
  directories they wait for through a process-wide operation id
  (``orbax.checkpoint._src.futures.synchronization.OperationIdGenerator``, a class attribute
  that every save advances and every writer reads at the moment it is created). Two saves
  in two threads (the experiments train two reward modes at once) read each other's id:
  a writer waits for the other save's directory signal, or for none, and writes into a
  directory not created yet, whose own creation then fails (``FileExistsError``) or removes
  files already written. :func:`save` therefore holds a module lock for the whole save, and
  managers save synchronously (no background thread outlives it), so a save is complete,
  digests included, before the next one in the process starts; it also holds
  :func:`jaxgrid.rundir.writing`, so that Ctrl-C never cuts a checkpoint in half.
- **Digests.** ``checkpoints.json`` beside ``checkpoints/`` maps every kept step to
  ``{"files": {file: sha256}, "records": sha256}``: the checkpoint's files, and the records
  (``metrics.jsonl``) of the chunks it holds. A checkpoint resumes only if both match, so a
  truncated or changed file, or an edited record, is never restored or reported as
  results. An entry without ``"records"`` (written before records were digested: a flat
  ``{file: sha256}``) verifies its files for :func:`verified_step`, but its records are
  unverified, so :func:`resume_point` never resumes from it.
- **Older layouts.** A checkpoint saved before a state field with a default existed, or in
  an older layout that an ``upgrade`` of :func:`restore` knows, is read as today's.

Knows nothing of the training loop (no import of :mod:`agents.runner`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import PPOConfig
from jaxgrid import io, rundir

__all__ = ["DIGESTS", "METRICS", "CheckpointError", "ResumeError", "finished", "kept",
           "make_manager", "record_digests", "records_sha256", "restore", "resume_point",
           "save", "stored", "verified_step"]  # fmt: skip

DIGESTS = "checkpoints.json"
METRICS = "metrics.jsonl"
_SAVING = threading.Lock()  # orbax's operation id is process-wide: one save at a time


class ResumeError(ValueError):
    """``out_dir``'s saved state cannot be resumed: a damaged or missing file, a checkpoint
    without its records, or a run made with another checker. Its message names the file;
    starting over (``resume=False``) is always safe, since the run is deterministic."""


class CheckpointError(OSError):
    """A checkpoint could not be saved. The message names the step, the directory and the
    last good checkpoint, which is kept (a resume continues from it)."""


def make_manager(path: Path):
    """An orbax ``CheckpointManager`` keeping the two newest steps in ``path``, saving
    synchronously: nothing of a save runs after :func:`save` returns."""
    import orbax.checkpoint as ocp

    options = ocp.CheckpointManagerOptions(
        max_to_keep=2, create=True, enable_async_checkpointing=False
    )
    # the one item's handler declared: its metadata (shapes, dtypes) reads before any restore
    return ocp.CheckpointManager(
        path.absolute(), options=options, item_handlers=ocp.StandardCheckpointHandler()
    )


def save_args(state):
    """The orbax arguments :func:`save` writes ``state`` with (a standard pytree save of
    :func:`stored`)."""
    import orbax.checkpoint as ocp

    return ocp.args.StandardSave(stored(state))


def stored(tree):
    """``tree`` as checkpoints hold it: its dataclasses as dicts of their pytree fields,
    without the fields that are None. Such a field is a reward mode's own state (the PID
    controller's, Saute's budget), absent in the other modes, so that adding one changes no
    other mode's checkpoint: those written before it existed still restore."""
    if dataclasses.is_dataclass(tree) and not isinstance(tree, type):
        return {
            f.name: stored(getattr(tree, f.name))
            for f in dataclasses.fields(tree)
            if f.metadata.get("pytree_node", True) and getattr(tree, f.name) is not None
        }
    if isinstance(tree, dict):
        return {k: stored(v) for k, v in tree.items()}
    return tree


def _rebuilt(template, saved):
    """The inverse of :func:`stored`: ``template`` (a state or its abstract shapes) with the
    values of ``saved`` in the fields it holds."""
    if dataclasses.is_dataclass(template) and not isinstance(template, type):
        return template.replace(**{k: _rebuilt(getattr(template, k), v) for k, v in saved.items()})
    if isinstance(template, dict):
        return {k: _rebuilt(template[k], v) for k, v in saved.items()}
    return saved


def kept(manager, out: Path | None, step: int | None = None) -> str:
    """Where the last good checkpoint is (``step``, else the manager's newest), only if one
    was really written."""
    if manager is None:
        return "no checkpoint was requested"
    step = manager.latest_step() if step is None else step
    if step is None:
        return f"no checkpoint was written yet (none in {out / 'checkpoints'})"
    return f"the last good checkpoint (chunk {step}) is kept in {out / 'checkpoints'}"


def save(manager, step: int, state, out: Path, records: Sequence[dict] | None,
         primary: bool = True) -> None:  # fmt: skip
    """Save ``state`` as checkpoint ``step`` and (on the ``primary`` process) record its
    digests with those of ``records`` (the run's records so far); return once it is all on
    disk. Any failure, orbax's included, is a :class:`CheckpointError` naming the last good
    checkpoint, which is left as it was."""
    with rundir.writing(), _SAVING:
        before = manager.latest_step()
        where = Path(manager.directory)
        try:
            if not manager.save(step, args=save_args(state)):
                raise CheckpointError(f"orbax refused to save checkpoint {step} in {where} "
                                      f"(an equal or newer step exists); "
                                      f"{kept(manager, out, before)}")  # fmt: skip
            manager.wait_until_finished()
            if primary:
                record_digests(manager, out, records)
        except CheckpointError:
            raise
        except Exception as e:  # orbax's and tensorstore's errors share no base class
            raise CheckpointError(f"checkpoint {step} could not be saved in {where} "
                                  f"({type(e).__name__}: {e}); {kept(manager, out, before)}"
                                  ) from e  # fmt: skip


def records_sha256(records: Sequence[dict]) -> str:
    """Digest of ``records`` as strict JSON with sorted keys, one line each, in order: the
    same for the records a run holds and for those records read back from its log."""
    lines = (json.dumps(io.to_jsonable(r), sort_keys=True, allow_nan=False) for r in records)
    return rundir.sha256_bytes("".join(line + "\n" for line in lines).encode("utf-8"))


def covered(records: Sequence[dict], chunks: int) -> list[dict]:
    """The records of the first ``chunks`` chunks (what a checkpoint of ``chunks`` holds)."""
    return [r for r in records if r["chunk"] < chunks]


def read_log(path: Path) -> list[dict]:
    """Every record in ``path`` (none if it is missing); :class:`ResumeError` naming it if
    a line or a record is damaged."""
    try:
        records = io.read_jsonl(path)
        for r in records:
            int(r["chunk"])
    except FileNotFoundError:
        return []
    except (ValueError, TypeError, KeyError) as e:
        raise ResumeError(f"{path}: damaged ({e}); delete it and the checkpoints beside it "
                          "to start over") from None  # fmt: skip
    return records


def step_digests(manager, step: int) -> dict[str, str]:
    """{file: sha256} of the files of checkpoint ``step``."""
    root = Path(manager.directory) / str(step)
    return {p.relative_to(root).as_posix(): rundir.sha256_file(p)
            for p in sorted(root.rglob("*")) if p.is_file()}  # fmt: skip


def record_digests(manager, out: Path, records: Sequence[dict] | None = None) -> None:
    """Record the digests of the manager's newest checkpoint (its files, and ``records`` of
    the chunks it holds; ``None``: those in ``out/metrics.jsonl``) in ``out/checkpoints.json``,
    keeping the entries of the other kept steps."""
    path = out / DIGESTS
    try:
        saved = io.read_json(path) if path.exists() else {}
    except ValueError:
        saved = {}  # rewritten below from the files themselves
    entries = {str(s): saved.get(str(s)) for s in manager.all_steps()}
    latest = int(manager.latest_step())
    records = read_log(out / METRICS) if records is None else records
    entries[str(latest)] = {"files": step_digests(manager, latest),
                            "records": records_sha256(covered(records, latest))}  # fmt: skip
    io.write_json(path, {k: v for k, v in entries.items() if v is not None})


def _files(entry) -> dict | None:
    """The file digests of a ``checkpoints.json`` entry, of either layout."""
    if not isinstance(entry, dict):
        return None
    return entry["files"] if isinstance(entry.get("files"), dict) else entry


def _recorded(manager, out: Path) -> dict:
    path = out / DIGESTS
    try:
        return io.read_json(path)
    except (FileNotFoundError, ValueError) as e:
        raise ResumeError(f"{path}: {e}; the checkpoints in {manager.directory} cannot be "
                          "verified: delete them to start over") from None  # fmt: skip


def _newest_matching(manager, problem: Callable[[int], str | None],
                     delete: bool) -> tuple[int | None, str | None]:  # fmt: skip
    """The newest step for which ``problem(step)`` is None, and the newest step's problem;
    each newer step is reported on stderr and deleted (if ``delete``: the run saves that
    step again)."""
    first = None
    for step in sorted(manager.all_steps(), reverse=True):
        why = problem(step)
        if why is None:
            return int(step), first
        first = first or why
        print(f"{Path(manager.directory) / str(step)}: {why}; "
              f"{'deleted, resuming from' if delete else 'reading'} an older one",
              file=sys.stderr)  # fmt: skip
        if delete:
            manager.delete(step)
    return None, first


def verified_step(manager, out: Path, delete: bool = True) -> int:
    """The newest checkpoint whose files match ``checkpoints.json`` (its records are not
    read); newer ones that do not (damaged, or written by a run killed before recording
    them) are deleted (if ``delete``), with a message. :class:`ResumeError` if none matches."""
    path = out / DIGESTS
    recorded = _recorded(manager, out)

    def problem(step):
        if _files(recorded.get(str(step))) != step_digests(manager, step):
            return f"damaged or unverified checkpoint (its files differ from {path})"
        return None

    step, _ = _newest_matching(manager, problem, delete)
    if step is None:
        raise ResumeError(f"{manager.directory}: no checkpoint matches {path}; delete them to "
                          "start over")  # fmt: skip
    return step


def resume_point(manager, out: Path, agents: list[tuple], ident) -> tuple[int, list[dict]]:
    """The newest checkpoint whose files and records both match ``checkpoints.json``, and
    its records (read from ``out/metrics.jsonl``; ``ident(record)`` is one of ``agents``).

    Newer checkpoints are deleted with a message on stderr, so the run redoes their chunks
    (the same numbers: it is deterministic) and logs their records anew. Records are never
    used unverified: an edited log, or digests without records' (an older run directory),
    match no checkpoint. :class:`ResumeError` naming the file if none matches, or if the
    log is damaged or misses records of a verified checkpoint."""
    path, log = out / DIGESTS, out / METRICS
    recorded, records = _recorded(manager, out), read_log(log)

    def problem(step):
        entry = recorded.get(str(step))
        if _files(entry) != step_digests(manager, step):
            return f"damaged or unverified checkpoint (its files differ from {path})"
        if not isinstance(entry, dict) or "records" not in entry:
            return f"{path} records no digest of its records, so {log} cannot be verified"
        if entry["records"] != records_sha256(covered(records, step)):
            return f"{log}: the records of its {step} chunks differ from those it was saved with"
        return None

    step, why = _newest_matching(manager, problem, delete=True)
    if step is None:
        raise ResumeError(f"{manager.directory}: no checkpoint can be resumed, since none "
                          f"matches {path} in both its files and {log} (the newest: {why}); "
                          "start over (resume=False, or delete them)")  # fmt: skip
    records = covered(records, step)
    _check_complete(log, records, step, agents, ident)
    return step, records


def _check_complete(path: Path, records: list[dict], chunks: int, agents: list[tuple],
                    ident) -> None:  # fmt: skip
    """Every agent has a record of each of the first ``chunks`` chunks (:class:`ResumeError`
    naming the file otherwise: the checkpoint outran its records)."""
    have = set()
    for r in records:
        try:
            have.add((ident(r), r["chunk"]))
        except KeyError:  # a record of another agent layout: not one of ours
            pass
    missing = [(s, c) for s in agents for c in range(chunks) if (s, c) not in have]
    if missing:
        raise ResumeError(
            f"{path}: records of {len(missing)} (seed, chunk) pairs, e.g. {missing[0]}, are "
            f"missing (truncated or deleted) though the checkpoint holds {chunks} chunks; "
            "delete it and the checkpoints beside it to start over"
        )


def restore(manager, step, abstract, shardings,
            upgrade: Callable[[dict], dict | None] | None = None):  # fmt: skip
    """The runner state of checkpoint ``step``. A checkpoint written before a
    :class:`RunnerState` field with a default existed is restored without it, and the field
    starts from zeros (such fields are added with zero as their initial value, and are read
    only by options that the configuration check proves off for such a run). One of an
    older layout goes to ``upgrade``, which returns it as today's :func:`stored` tree (None:
    no layout it knows)."""
    import orbax.checkpoint as ocp

    if shardings is not None:
        target = jax.tree.map(
            lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s), abstract, shardings
        )
    else:
        target = abstract
    try:
        return _rebuilt(
            target, manager.restore(step, args=ocp.args.StandardRestore(stored(target)))
        )
    except Exception as e:  # orbax's and tensorstore's errors share no base class
        error = e
    # Fields are added last, with a default: try without the newest one, then two, ...
    fields = dataclasses.fields(target)
    defaulted = [f.name for f in fields
                 if f.default_factory is not dataclasses.MISSING
                 and jax.tree.leaves(getattr(target, f.name))]  # fmt: skip
    restored = None
    for k in range(1, len(defaulted) + 1):
        added = defaulted[-k:]
        older = {k: v for k, v in stored(target).items() if k not in added}
        try:
            restored = manager.restore(step, args=ocp.args.StandardRestore(older))
            break
        except Exception:
            continue
    if restored is None and upgrade is not None:
        restored = _upgraded_state(manager, step, target, upgrade)
        if restored is not None:
            return restored
    if restored is None:
        raise ResumeError(f"{manager.directory}: checkpoint {step} cannot be restored "
                          f"({type(error).__name__}: {error}); delete it to start over"
                          ) from error  # fmt: skip

    def zeros(a):
        return _placed(np.zeros(a.shape, a.dtype), a)

    print(f"{manager.directory}: checkpoint {step} predates {', '.join(added)}; "
          "starting from zeros", file=sys.stderr)  # fmt: skip
    filled = {n: jax.tree.map(zeros, getattr(target, n)) for n in added}
    return _rebuilt(target, restored).replace(**filled)


def _upgraded_state(manager, step, target, upgrade):
    """Checkpoint ``step`` read in its own layout, ``upgrade``-d and placed as ``target``;
    None when it cannot be read so or ``upgrade`` knows no such layout."""
    import orbax.checkpoint as ocp

    want = stored(target)
    try:  # the saved tree's shapes (metadata, no array read) where its keys differ from today's
        raw = manager.item_metadata(step).tree
        saved = manager.restore(step, args=ocp.args.StandardRestore(_saved_layout(want, raw)))
    except Exception:  # orbax's and tensorstore's errors share no base class
        return None
    try:
        new = upgrade(saved)
    except ValueError as e:
        raise ResumeError(f"{manager.directory}: checkpoint {step}, of an older layout, "
                          f"cannot be read ({e}); delete it to start over") from e  # fmt: skip
    if new is None:
        return None
    if jax.tree.structure(new) != jax.tree.structure(want) or any(
        np.shape(a) != b.shape or np.asarray(a).dtype != b.dtype
        for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(want), strict=True)
    ):
        raise ResumeError(f"{manager.directory}: checkpoint {step}, of an older layout, does "
                          "not fit this run's state; delete it to start over")  # fmt: skip
    print(f"{manager.directory}: checkpoint {step} is of an older layout; read it as "
          "today's", file=sys.stderr)  # fmt: skip
    return _rebuilt(target, jax.tree.map(_placed, new, want))


def _placed(a, like):
    sharding = getattr(like, "sharding", None)
    return jnp.asarray(a) if sharding is None else jax.device_put(np.asarray(a), sharding)


def _saved_layout(want, raw):
    """A restore target for a checkpoint whose saved tree ``raw`` (its metadata) differs from
    ``want`` in some dicts' keys: ``want`` where they agree, ``raw``'s shapes where they
    differ."""
    if isinstance(want, dict) and isinstance(raw, dict):
        if set(want) != set(raw):
            return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), raw)
        return {k: _saved_layout(want[k], raw[k]) for k in want}
    return want


def finished(out: Path, config: PPOConfig) -> bool:
    """Whether ``out``'s checkpoint digests list the run's last chunk: a guess, for
    compiling ahead only what a resume needs (a resume still verifies the files)."""
    try:
        return str(config.num_chunks) in io.read_json(out / DIGESTS)
    except (FileNotFoundError, ValueError):
        return False
