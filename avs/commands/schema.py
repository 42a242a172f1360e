"""``avs schema export DIR``: one JSON Schema per message, for tools outside this project."""

from __future__ import annotations

import argparse
from pathlib import Path

from schemas.export import export_json_schemas


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("schema", help="work with the message schemas")
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    export = actions.add_parser(
        "export", help="write <Message>.json (JSON Schema 2020-12) for every message into DIR"
    )
    export.add_argument(
        "directory", type=Path, metavar="DIR", help="where the JSON Schemas are written"
    )
    export.set_defaults(func=_export)


def _export(args: argparse.Namespace) -> int:
    paths = export_json_schemas(args.directory)
    print(f"wrote {len(paths)} schemas to {args.directory}")
    return 0
