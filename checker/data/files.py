"""Checker dataset files: :class:`CheckerDataset`, numpy arrays of labelled windows and their
metadata, saved as ``<path>.npz`` (the arrays) beside ``<path>.json`` (the metadata, the
arrays' sha256 and the vocabulary the token ids were made with)."""

from __future__ import annotations

import dataclasses
import io
import os
import zipfile
from collections.abc import Sequence

import numpy as np

from checker.store import check_vocab, vocab_meta
from jaxgrid.io import atomic_write, read_json, write_json
from jaxgrid.rundir import sha256_bytes, sha256_file

FORMAT_VERSION = 1
#: The per-row arrays every dataset holds.
CORE = ("windows", "tokens", "labels", "template_id", "constraint_type", "scenario")


@dataclasses.dataclass
class CheckerDataset:
    """Numpy arrays of ``N`` windows and their labels, plus metadata.

    Attributes:
        windows: uint8 ``(N, n, V, V, 3)``, oldest frame first.
        tokens: int32 ``(N, L)`` constraint token ids.
        labels: uint8 ``(N,)``, 1 = violation within the lookahead (see the module docs).
        template_id: int32 ``(N,)``, ``jaxgrid.sentences.TEMPLATES`` index.
        constraint_type: int32 ``(N,)``, paper type 1-5.
        scenario: str ``(N,)``, the env id each row came from.
        extras: per-row arrays of full-episode datasets (:data:`EPISODE_FIELDS`), else empty.
        meta: JSON-serialisable metadata (env id, split, window, lookahead, rates, counts...).
    """

    windows: np.ndarray
    tokens: np.ndarray
    labels: np.ndarray
    template_id: np.ndarray
    constraint_type: np.ndarray
    scenario: np.ndarray
    extras: dict = dataclasses.field(default_factory=dict)
    meta: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        n = len(self.labels)
        for name in CORE:
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"CheckerDataset.{name} has {len(getattr(self, name))} rows, labels has {n}"
                )
        for name, arr in self.extras.items():
            if len(arr) != n:
                raise ValueError(f"CheckerDataset.extras[{name!r}] has {len(arr)} rows, not {n}")

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def window(self) -> int:
        return int(self.windows.shape[1])

    @property
    def positive_fraction(self) -> float:
        return float(np.mean(self.labels)) if len(self) else 0.0

    def subset(self, index: np.ndarray) -> CheckerDataset:
        """Rows ``index`` (an int or bool array) as a new dataset; metadata counts updated."""
        index = np.asarray(index)
        arrays = {name: getattr(self, name)[index] for name in CORE}
        extras = {k: v[index] for k, v in self.extras.items()}
        return CheckerDataset(**arrays, extras=extras, meta=dict(self.meta)).counted()

    def counted(self, **more) -> CheckerDataset:
        """This dataset with its metadata's counts (rows, positives, positive share) set from
        its rows, and ``more`` beside them; updated in place and returned."""
        self.meta.update(num_samples=len(self), num_positive=int(np.sum(self.labels)),
                         positive_fraction=self.positive_fraction, **more)  # fmt: skip
        return self

    def split(self, fractions: Sequence[float], seed: int = 0) -> tuple[CheckerDataset, ...]:
        """Random disjoint parts of sizes ``fractions`` (summing to 1).

        Balanced datasets are split per class (stratified), so each part keeps the positive
        fraction; full-episode datasets are split by whole episodes.
        """
        fractions = [float(f) for f in fractions]
        if not fractions or any(f < 0 for f in fractions) or abs(sum(fractions) - 1) > 1e-6:
            raise ValueError(f"split fractions must be >= 0 and sum to 1, got {fractions}")
        rng = np.random.default_rng(seed)
        parts: list[list[np.ndarray]] = [[] for _ in fractions]
        if "episode" in self.extras:
            groups = [np.unique(self.extras["episode"])]
            keys = self.extras["episode"]
        else:
            groups = [np.flatnonzero(self.labels == c) for c in (0, 1)]
            keys = None
        for members in groups:
            members = rng.permutation(members)
            bounds = np.round(np.cumsum([0.0] + fractions) * len(members)).astype(int)
            for p in range(len(fractions)):
                chosen = members[bounds[p] : bounds[p + 1]]
                parts[p].append(chosen if keys is None else np.flatnonzero(np.isin(keys, chosen)))
        out = []
        for p in parts:
            idx = (
                np.sort(np.concatenate(p))
                if keys is not None
                else rng.permutation(np.concatenate(p))
            )
            out.append(self.subset(idx))
        return tuple(out)

    # ---------------------------------------------------------------- persistence
    @staticmethod
    def _paths(path: str | os.PathLike) -> tuple[str, str]:
        base = os.fspath(path)
        if base.endswith(".npz"):
            base = base[:-4]
        elif base.endswith(".json"):
            base = base[:-5]
        return base + ".npz", base + ".json"

    def save(self, path: str | os.PathLike) -> tuple[str, str]:
        """Write ``<path>.npz`` (arrays) and ``<path>.json`` (metadata with the npz's sha256);
        returns both paths. Each is written atomically, the arrays first."""
        npz, js = self._paths(path)
        arrays = {name: getattr(self, name) for name in CORE}
        arrays.update({f"extra_{k}": v for k, v in self.extras.items()})
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        atomic_write(npz, buf.getvalue())
        meta = {
            "format_version": FORMAT_VERSION,
            "npz_sha256": sha256_bytes(buf.getvalue()),
            **self.meta,
            **vocab_meta(),
        }
        write_json(js, meta)
        return npz, js

    @classmethod
    def load(cls, path: str | os.PathLike) -> CheckerDataset:
        """Read a dataset written by :meth:`save` (``path`` with or without extension).

        ``FileNotFoundError`` names a missing file; ``ValueError`` names the file if it was made
        for another vocabulary or ``MAX_LEN``, or is damaged: the npz must match the sha256
        recorded in the JSON (a dataset saved before checksums were recorded is read without
        that check).
        """
        npz, js = cls._paths(path)
        for p in (js, npz):
            if not os.path.isfile(p):
                raise FileNotFoundError(f"checker dataset file not found: {p}")
        meta = read_json(js)
        check_vocab(meta, f"dataset {js}")
        recorded = meta.get("npz_sha256")
        if recorded is not None and sha256_file(npz) != recorded:
            raise ValueError(f"{npz}: damaged dataset file (truncated or changed: its sha256 "
                             f"differs from the one in {js}); delete both files and collect "
                             "the data again")  # fmt: skip
        try:
            with np.load(npz, allow_pickle=False) as z:
                arrays = {name: z[name] for name in CORE}
                extras = {k[len("extra_") :]: z[k] for k in z.files if k.startswith("extra_")}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
            raise ValueError(f"{npz}: damaged dataset file ({type(e).__name__}: {e})") from e
        own = ("vocab", "max_len", "format_version", "npz_sha256")
        meta = {k: v for k, v in meta.items() if k not in own}
        return cls(**arrays, extras=extras, meta=meta)
