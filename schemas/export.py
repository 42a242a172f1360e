"""JSON Schema export: one file per message, so outside tools can decode the streams."""

from __future__ import annotations

import json
from pathlib import Path

from schemas.base import REGISTRY


def json_schema(name: str) -> dict:
    """The JSON Schema (draft 2020-12) of the registered message ``name``."""
    schema = REGISTRY[name].model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    return schema


def json_schema_text(name: str) -> str:
    """The text of ``<name>.json`` as ``avs schema export`` writes it (and recordings embed)."""
    return json.dumps(json_schema(name), indent=2, sort_keys=False) + "\n"


def json_schemas() -> dict[str, dict]:
    """Schema name → JSON Schema (draft 2020-12) of every registered message."""
    return {name: json_schema(name) for name in sorted(REGISTRY)}


def export_json_schemas(directory: Path) -> list[Path]:
    """Write ``<Name>.json`` for every message into ``directory``; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in sorted(REGISTRY):
        path = directory / f"{name}.json"
        path.write_text(json_schema_text(name))
        paths.append(path)
    return paths
