"""The disk cache of Monte Carlo results (searchlight profiles, scene references).

An entry is ``<prefix>_<sha256 of the key>.pt`` in :func:`mc_cache_dir`, holding the key
(JSON) and the result (a dict of tensors and numbers). The key must hold everything the
result depends on, including a digest of the code; a file whose stored key differs (a hash
collision) or that cannot be read is recomputed. Writes are atomic (temporary file, then
``os.replace``), so concurrent writers of one key are harmless.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

__all__ = ["mc_cache_dir", "cached_entry"]


def mc_cache_dir() -> Path:
    """``$SSSBENCH_CACHE_DIR/mc``, else ``~/.cache/sssbench/mc``."""
    root = os.environ.get("SSSBENCH_CACHE_DIR")
    return (Path(root) if root else Path.home() / ".cache" / "sssbench") / "mc"


def cached_entry(
    prefix: str, key: dict[str, Any], compute: Callable[[], dict[str, Any]], cache: bool = True
) -> dict[str, Any]:
    """The result of ``key``: loaded, or ``compute()`` and stored (``cache=False``: neither)."""
    blob = json.dumps(key, sort_keys=True)
    path = mc_cache_dir() / f"{prefix}_{hashlib.sha256(blob.encode()).hexdigest()[:32]}.pt"
    if cache and path.is_file():
        try:
            entry = torch.load(path, weights_only=True)
            if entry["key"] == blob:
                return entry["result"]
        except Exception:  # noqa: BLE001 - a corrupt entry is recomputed
            pass
    result = compute()
    if cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        torch.save({"key": blob, "result": result}, tmp)
        os.replace(tmp, path)
    return result
