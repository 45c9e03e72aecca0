"""The exact-reference cache shared by the app and the experiments.

A reference image is stored as ``reference_<hash>.pt`` where the hash covers everything the
image depends on (:func:`reference_key`): the package's source code (:func:`code_digest`),
the scene and its
parameters, resolution, seed, dtype, the profile's *content* (not its name: a changed table
never hits an old entry), the reference's options and the stages that change the light it
integrates. Writes are atomic (a temporary file then ``os.replace``), so concurrent writers of
one key are harmless and a killed run leaves no half-written entry; an unreadable entry is
recomputed. Hits and misses are counted in :data:`STATS` (logged once per sweep, not per run).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

from sssbench._digest import code_digest, profile_digest
from sssbench.store.tracking import config_hash

log = logging.getLogger("sssbench")

__all__ = [
    "code_digest",
    "default_cache_dir",
    "profile_digest",
    "reference_key",
    "cached_reference",
    "STATS",
]

#: hits / misses of this process
STATS = {"hit": 0, "miss": 0}


def default_cache_dir() -> Path:
    """``$SSSBENCH_CACHE_DIR/references``, else ``~/.cache/sssbench/references``."""
    root = os.environ.get("SSSBENCH_CACHE_DIR")
    return (Path(root) if root else Path.home() / ".cache" / "sssbench") / "references"


def reference_key(
    *,
    scene: str,
    scene_params: Mapping[str, Any],
    profile: Any,
    resolution: tuple[int, int],
    seed: int,
    dtype: str,
    reference_params: Mapping[str, Any] | None = None,
    stages: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """What a reference image depends on (see the module docstring)."""
    return {
        "code": code_digest(),
        "scene": scene,
        "scene_params": dict(scene_params),
        "profile": profile_digest(profile),
        "resolution": list(resolution),
        "seed": seed,
        "dtype": dtype,
        "reference_params": dict(reference_params or {}),
        "stages": {k: v for k, v in sorted((stages or {}).items()) if v is not None},
    }


def cached_reference(
    key: Mapping[str, Any],
    compute: Callable[[], torch.Tensor],
    cache_dir: Path | None = None,
    *,
    shape: tuple[int, ...] | None = None,
) -> tuple[torch.Tensor, bool, float]:
    """The reference image of ``key``, loaded or computed with ``compute()`` and stored.

    Returns:
        ``(image, cache_hit, compute_ms)`` (``compute_ms`` as stored with the entry).
    """
    path = (cache_dir or default_cache_dir()) / f"reference_{config_hash(dict(key))}.pt"
    if path.is_file():
        try:
            entry = torch.load(path, weights_only=True)
            image = entry["image"]
            if shape is None or tuple(image.shape) == tuple(shape):
                STATS["hit"] += 1
                log.debug("reference cache hit: %s", path)
                return image, True, float(entry.get("ms", float("nan")))
        except Exception as exc:  # a corrupt entry is recomputed
            log.warning("reference cache entry %s unreadable (%s); recomputing", path, exc)
    STATS["miss"] += 1
    log.info("computing the exact reference (cached as %s)", path.name)
    start = time.perf_counter()
    image = compute()
    ms = (time.perf_counter() - start) * 1e3
    store_reference(path, image, key, ms)
    return image, False, ms


def store_reference(path: Path, image: torch.Tensor, key: Mapping[str, Any], ms: float) -> None:
    """Write one cache entry atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    torch.save({"image": image.detach().cpu(), "key": json.dumps(dict(key)), "ms": ms}, tmp)
    os.replace(tmp, path)
