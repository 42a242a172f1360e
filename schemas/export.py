"""JSON Schema export: one file per message, so outside tools can decode the streams."""

from __future__ import annotations

import json
from pathlib import Path

from schemas.base import REGISTRY


def json_schemas() -> dict[str, dict]:
    """Schema name → JSON Schema (draft 2020-12) of every registered message."""
    out = {}
    for name, cls in sorted(REGISTRY.items()):
        schema = cls.model_json_schema()
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        out[name] = schema
    return out


def export_json_schemas(directory: Path) -> list[Path]:
    """Write ``<Name>.json`` for every message into ``directory``; returns the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, schema in json_schemas().items():
        path = directory / f"{name}.json"
        path.write_text(json.dumps(schema, indent=2, sort_keys=False) + "\n")
        paths.append(path)
    return paths
