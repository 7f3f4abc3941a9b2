"""The trained networks of the reconstruct task's learned methods: trained once per (training set,
method, budget, code), cached, shared by every job and run that needs them.

Training set: :func:`methods.pointcloud.training_set.training_shapes` with the budget's ``training_shapes``
built-in parts (generator seed :data:`methods.pointcloud.training_set.DEFAULT_TRAINING_SEED`, disjoint from every
built-in test shape by construction and by hash) plus every mesh of the run's ``train_dirs`` (by
default the Thingi10K folder of ``../shared/data`` where it exists). Cache key: the training set's
digest (content hashes and names), the method, every value of its budget record (the fields its
family reads, not the budget's name), the training seed and the code
digest of the method's module and the training loop (:func:`tasks.cache.code_digest`).
Entries: ``<cache root>/trained_networks/<method>_<key>.pt``, written with a checksum; a job that needs a
network another job is training waits on the entry's lock (``locks/``) and then loads it.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Callable

from foundation.storage import CacheStats, entry_lock, read_entry, write_checked

#: The cache folder of the trained networks (every learned reconstruction method's, one file each).
TRAINED_NETWORKS = "trained_networks"
#: Extra training meshes used when a run names none: the Thingi10K meshes of ../shared/data.
DEFAULT_TRAIN_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "thingi10k"


def training_folders_digest(dirs: tuple[str, ...]) -> dict[str, str]:
    """{folder: 16 hex digits of the SHA-256 over its mesh files' relative paths and bytes}: what a
    run's extra training meshes are, part of its identity (a folder whose files changed is another
    training set)."""
    from datasets import get_dataset

    digests = {}
    for folder in dirs:
        dataset = get_dataset("meshes", data_dir=folder)
        h = hashlib.sha256()
        for path in dataset.files:
            h.update(path.relative_to(dataset.data_dir).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(path.read_bytes()).digest())
        digests[folder] = h.hexdigest()[:16]
    return digests


def default_train_dirs() -> tuple[str, ...]:
    """The default extra training folders: the shared Thingi10K folder where it exists, else none."""
    return (str(DEFAULT_TRAIN_DIR.resolve()),) if DEFAULT_TRAIN_DIR.is_dir() else ()


@lru_cache(maxsize=8)
def _shapes(count: int, dirs: tuple[str, ...]):
    from methods.pointcloud.training_set import DEFAULT_TRAINING_SEED, training_shapes

    return tuple(training_shapes(count=count, seed=DEFAULT_TRAINING_SEED, extra_dirs=[Path(d) for d in dirs]))


def network_training_record(method, budget, train_dirs: tuple[str, ...]):
    """The :class:`methods.core.training_record.TrainingRecord` of the network ``method`` trains at
    ``budget`` on the built-in parts and ``train_dirs``: its training shapes' content hashes."""
    from methods.core.training_record import TrainingRecord

    shapes = _shapes(budget.training_shapes, tuple(train_dirs))
    where = f" + {', '.join(train_dirs)}" if train_dirs else ""
    return TrainingRecord(f"{method.name}'s network ({budget.name} budget): {len(shapes)} shapes, built-in training "
                          f"parts{where}", content_hashes=frozenset(s.content_hash for s in shapes))


def trained_network_key(method, budget, train_dirs: tuple[str, ...]) -> tuple[str, tuple]:
    """(cache key, training shapes) of the network ``method`` trains at ``budget``
    (:func:`tasks.cache.network_key`)."""
    from tasks.cache import network_key
    from methods.pointcloud.training_set import DEFAULT_TRAINING_SEED, training_set_digest

    shapes = _shapes(budget.training_shapes, tuple(train_dirs))
    return network_key(method, budget, training_set_digest(shapes), DEFAULT_TRAINING_SEED), shapes


def network_path(cache_root: str | Path, method, key: str) -> Path:
    """Where the cache under ``cache_root`` keeps ``method``'s network of cache ``key``."""
    return Path(cache_root) / TRAINED_NETWORKS / f"{method.name}_{key}.pt"


def network_is_cached(method, budget, train_dirs: tuple[str, ...], cache_root: str | Path) -> bool:
    """Whether the cache under ``cache_root`` holds the network ``method`` trains at ``budget`` (a
    file is there; :func:`trained_network` still checks it when it reads it)."""
    return network_path(cache_root, method, trained_network_key(method, budget, train_dirs)[0]).is_file()


def trained_network(method, budget, train_dirs: tuple[str, ...], cache_root: str | Path, device=None,
                    progress: Callable[..., None] | None = None, stats: CacheStats | None = None):
    """(model in eval mode, facts) of ``method`` at ``budget`` (its own :meth:`train_network`): from the cache, or
    trained now (and cached). Facts: ``network_key``, ``trained`` (1 if trained here), and after a
    training ``train_steps``, ``train_loop_s``, ``train_samples_per_s``, ``train_final_loss``."""
    from methods.core.weights import WeightsError
    from methods.pointcloud.training_set import DEFAULT_TRAINING_SEED

    key, shapes = trained_network_key(method, budget, train_dirs)
    root = Path(cache_root)
    path = network_path(root, method, key)
    facts = {"network_key": key, "trained": 0, "training_shapes": len(shapes)}
    stats = CacheStats() if stats is None else stats
    with entry_lock(root, f"{TRAINED_NETWORKS}_{method.name}_{key}"):
        model = read_entry(path, stats, "network", lambda data: method.network_from_bytes(data, device=device),
                           refused=(WeightsError, ValueError))  # not a plain weights record: refused unread
        if model is not None:
            return model, facts
        result = method.train_network(list(shapes), budget, seed=DEFAULT_TRAINING_SEED, device=device,
                                      progress=progress)
        write_checked(path, method.network_to_bytes(result, budget))
    facts.update(trained=1, train_steps=result.steps, train_loop_s=result.seconds,
                 train_samples_per_s=result.samples_per_s, train_final_loss=result.final_loss)
    return result.model, facts
