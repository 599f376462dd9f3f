"""Stored planner artifacts: content-addressed, atomic, never pickled.

A plan stage with ``artifact: FILE`` stores what the planner built. The file
records a content key: a hash of the scene (obstacles, meshes' bytes, bounds),
the space, the plugin (name, package version, artifact format) and its
settings. A later run whose key matches loads the file instead of building;
a different key rebuilds and overwrites it; a file that cannot be read is an
:class:`~surgiplan.errors.ArtifactError` (it is never silently replaced, so
a roadmap that took hours is not lost to a typo).
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from .errors import ArtifactError
from .hookspecs import PluginInfo
from .planning import Planner, PlanningProblem
from .storage import load_bundle, save_bundle, to_jsonable

log = logging.getLogger(__name__)

FORMAT = "surgiplan-artifact"


def artifact_key(plugin: PluginInfo, settings: BaseModel, problem: PlanningProblem) -> str:
    """Content hash of everything the built artifact depends on."""
    identity = {
        "plugin": plugin.name,
        "package": plugin.package,
        "version": plugin.version,
        "artifact_version": getattr(plugin.cls, "artifact_version", 1),
        "settings": settings.model_dump(mode="json"),
        "scene": problem.scene.spec(),
        "space": problem.space.spec(),
        "clearance_threshold": None if problem.clearance_threshold is None else problem.clearance_threshold.value,
    }
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()


def save_artifact(path: Path, planner: Planner, artifact: Any, key: str, plugin: PluginInfo) -> None:
    data = planner.save_artifact(artifact)
    arrays = {k: v for k, v in data.items() if isinstance(v, np.ndarray)}
    values = to_jsonable({k: v for k, v in data.items() if not isinstance(v, np.ndarray)})
    meta = {"format": FORMAT, "key": key, "plugin": plugin.name, "values": values}
    save_bundle(path, arrays, meta)
    log.info("stored the %s artifact in %s (%.3g MB)", plugin.name, path, path.stat().st_size / 1e6)


def load_artifact(
    path: Path, planner: Planner, key: str, plugin: PluginInfo, problem: PlanningProblem, *, location: str | None = None
) -> Any | None:
    """The stored artifact if its key matches; ``None`` when it must be rebuilt."""
    if not path.exists():
        log.info("no stored artifact at %s yet; building", path)
        return None
    try:
        arrays, meta = load_bundle(path)
    except ValueError as exc:
        raise ArtifactError(
            f"artifact file {path} is corrupt: {exc}; delete it to rebuild", location=location
        ) from None
    if meta.get("format") != FORMAT or "key" not in meta:
        raise ArtifactError(f"{path} is not a surgiplan artifact; delete it or choose another file", location=location)
    if meta["key"] != key:
        log.info("%s was built from another scene, space or settings; rebuilding", path)
        return None
    data: Mapping[str, Any] = {**meta.get("values", {}), **arrays}
    log.info("reusing the stored %s artifact %s (same scene, space and settings)", plugin.name, path)
    try:
        return planner.load_artifact(data, problem)
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise ArtifactError(
            f"artifact file {path} is corrupt: {type(exc).__name__}: {exc}; delete it to rebuild", location=location
        ) from None
