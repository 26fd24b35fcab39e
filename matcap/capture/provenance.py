"""The provenance record's parts: where a component's weights came from
(``_component_record``, its settings ``component_settings``) and the versions of the packages that ran (``_package_versions``).
"""

from __future__ import annotations

import hashlib
import json

import torch


def _sha256(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def _component_record(component, name: str | None) -> dict:
    """Where a component's weights came from: its folder and a hash of its config."""
    if component is None:
        return {"name": name, "used": False}
    model = getattr(getattr(component, "pipeline", None), "model", None) or getattr(component, "model", component)
    config = getattr(model, "config", None)
    record: dict = {"name": name or type(component).__name__, "class": type(component).__name__}
    if config is not None:
        config = dict(config)
        record["folder"] = str(config.get("_name_or_path")) if config.get("_name_or_path") else None
        record["config_sha256"] = _sha256({k: v for k, v in config.items() if not k.startswith("_")})
    record.update(component_settings(component))
    return record


#: Settings a relighter carries on itself rather than in a config (sampling steps,
#: samples, the mode for photos above its native size).
COMPONENT_SETTINGS = ("steps", "num_samples", "large")


def component_settings(component) -> dict:
    """The ``COMPONENT_SETTINGS`` a component has, by name."""
    return {attr: getattr(component, attr) for attr in COMPONENT_SETTINGS if hasattr(component, attr)}


def _package_versions() -> dict:
    from importlib import metadata

    versions = {"python": ".".join(map(str, __import__("sys").version_info[:3])), "torch": torch.__version__}
    for dist in ("dgrsise", "warp-lang", "diffusers"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    return versions
