"""The whole message contract (``shared/schema/``) in one place: every message kind, its model and version, its
parser, and the JSON Schema files generated from the models (``edge-ips schema --out shared/schema``).

The rovers' messages and the edge's status are in :mod:`edge.messages`; several boards' detections and the fusers'
status in :mod:`edge.board_messages`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from edge.board_messages import DetectionsV1, FuserStatusV1, parse_detections, parse_fuser_status
from edge.messages import (
    ROVER_STATUS_VERSION,
    FormationV1,
    PoseV1,
    RoverStatusV2,
    StatusV1,
    parse_formation,
    parse_pose,
    parse_rover_status,
    parse_status,
)

MODELS: dict[str, type[BaseModel]] = {
    "pose": PoseV1,
    "formation": FormationV1,
    "status": StatusV1,
    "rover_status": RoverStatusV2,
    "detections": DetectionsV1,
    "fuser_status": FuserStatusV1,
}
MODEL_VERSIONS: dict[str, int] = {
    "pose": 1,
    "formation": 1,
    "status": 1,
    "rover_status": ROVER_STATUS_VERSION,
    "detections": 1,
    "fuser_status": 1,
}
PARSERS: dict[str, Callable[[bytes], BaseModel]] = {
    "pose": parse_pose,
    "formation": parse_formation,
    "status": parse_status,
    "rover_status": parse_rover_status,
    "detections": parse_detections,
    "fuser_status": parse_fuser_status,
}


def schema_file(kind: str) -> str:
    """The committed schema's file name of a message kind: ``pose.v1.schema.json``, ``rover_status.v2...``."""
    return f"{kind}.v{MODEL_VERSIONS[kind]}.schema.json"


def schema_documents() -> dict[str, dict[str, Any]]:
    """``{file name: JSON Schema}`` for every message and version, as committed under ``shared/schema/``."""
    docs: dict[str, dict[str, Any]] = {}
    for name, model in MODELS.items():
        schema = model.model_json_schema(mode="validation")
        schema = {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "$id": f"https://edge-ips.invalid/schema/{schema_file(name)}",
            **schema,
        }
        docs[schema_file(name)] = schema
    return docs


def render_schema(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, sort_keys=False) + "\n"


def write_schemas(directory: Path) -> list[Path]:
    """Write every schema document into ``directory``; returns the paths written."""
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name, doc in schema_documents().items():
        path = directory / name
        path.write_text(render_schema(doc))
        written.append(path)
    return written
