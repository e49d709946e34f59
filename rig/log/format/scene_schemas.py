"""JSON Schemas of Foxglove's well-known 3D messages, field for field as Foxglove publishes them.

The 3D panel of Foxglove and Lichtblick recognises a channel by its schema *name*
(`foxglove.FrameTransforms`, `foxglove.SceneUpdate`); the schema's fields become the message
fields the other panels show. Each schema here has the properties, types and `required` lists of
Foxglove's published JSON Schemas (the npm package `@foxglove/schemas`, `jsonschema` export, 2.1),
so a payload that validates against ours validates against theirs: every property is required, as
there, and `rig.log.format.link_scene` fills every one (empty arrays for the primitives it does not draw).
`tests/test_log_foxglove_schemas.py` validates logged messages against the official schemas with
Ajv and compares the `required` lists. Enums are numbers; times are `{sec, nsec}`.
"""

from __future__ import annotations

from typing import Any


def _object(title: str, properties: dict[str, Any], description: str = "") -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "object", "title": title, "properties": properties}
    if description:
        schema["description"] = description
    schema["required"] = list(properties)
    return schema


def _numbers(title: str, names: str) -> dict[str, Any]:
    return _object(title, {name: {"type": "number"} for name in names})


def _array(items: dict[str, Any], description: str) -> dict[str, Any]:
    return {"type": "array", "items": items, "description": description}


_TIME = _object(
    "time",
    {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
)
_DURATION = _object(
    "duration",
    {"sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
)
_VECTOR3 = _numbers("foxglove.Vector3", "xyz")
_POINT3 = _numbers("foxglove.Point3", "xyz")
_QUATERNION = _numbers("foxglove.Quaternion", "xyzw")
_COLOR = _numbers("foxglove.Color", "rgba")
_POSE = _object("foxglove.Pose", {"position": _VECTOR3, "orientation": _QUATERNION})

_FRAME_TRANSFORM = _object(
    "foxglove.FrameTransform",
    {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _VECTOR3,
        "rotation": _QUATERNION,
    },
    "The pose of the child frame in its parent frame",
)

_LINE_TYPE = {
    "title": "foxglove.LineType",
    "description": "How the points are connected",
    "oneOf": [
        {"title": "LINE_STRIP", "const": 0},
        {"title": "LINE_LOOP", "const": 1},
        {"title": "LINE_LIST", "const": 2},
    ],
}
_DELETION_TYPE = {
    "title": "foxglove.SceneEntityDeletionType",
    "description": "What to delete",
    "oneOf": [{"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}],
}

_INDICES = _array({"type": "integer", "minimum": 0}, "Indices into the points and colors")
_KEY_VALUE = _object("foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}})
_SPHERE = _object("foxglove.SpherePrimitive", {"pose": _POSE, "size": _VECTOR3, "color": _COLOR})
_CUBE = _object("foxglove.CubePrimitive", {"pose": _POSE, "size": _VECTOR3, "color": _COLOR})
_CYLINDER = _object(
    "foxglove.CylinderPrimitive",
    {
        "pose": _POSE,
        "size": _VECTOR3,
        "bottom_scale": {"type": "number"},
        "top_scale": {"type": "number"},
        "color": _COLOR,
    },
)
_LINE = _object(
    "foxglove.LinePrimitive",
    {
        "type": _LINE_TYPE,
        "pose": _POSE,
        "thickness": {"type": "number"},
        "scale_invariant": {"type": "boolean"},
        "points": _array(_POINT3, "Points along the line"),
        "color": _COLOR,
        "colors": _array(_COLOR, "Per-point colors (empty: `color` for all)"),
        "indices": _INDICES,
    },
)
_TRIANGLES = _object(
    "foxglove.TriangleListPrimitive",
    {
        "pose": _POSE,
        "points": _array(_POINT3, "Vertices, three per triangle"),
        "color": _COLOR,
        "colors": _array(_COLOR, "Per-vertex colors (empty: `color` for all)"),
        "indices": _INDICES,
    },
)
_MODEL = _object(
    "foxglove.ModelPrimitive",
    {
        "pose": _POSE,
        "scale": _VECTOR3,
        "color": _COLOR,
        "override_color": {"type": "boolean"},
        "url": {"type": "string"},
        "media_type": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
)
_ARROW = _object(
    "foxglove.ArrowPrimitive",
    {
        "pose": _POSE,
        "shaft_length": {"type": "number"},
        "shaft_diameter": {"type": "number"},
        "head_length": {"type": "number"},
        "head_diameter": {"type": "number"},
        "color": _COLOR,
    },
)
_TEXT = _object(
    "foxglove.TextPrimitive",
    {
        "pose": _POSE,
        "billboard": {"type": "boolean"},
        "font_size": {"type": "number"},
        "scale_invariant": {"type": "boolean"},
        "color": _COLOR,
        "text": {"type": "string"},
    },
)
_ENTITY = _object(
    "foxglove.SceneEntity",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "id": {"type": "string"},
        "lifetime": _DURATION,
        "frame_locked": {"type": "boolean"},
        "metadata": _array(_KEY_VALUE, "Additional user-provided metadata"),
        "arrows": _array(_ARROW, "Arrow primitives"),
        "cubes": _array(_CUBE, "Cube primitives"),
        "spheres": _array(_SPHERE, "Sphere primitives"),
        "cylinders": _array(_CYLINDER, "Cylinder primitives"),
        "lines": _array(_LINE, "Line primitives"),
        "triangles": _array(_TRIANGLES, "Triangle list primitives"),
        "texts": _array(_TEXT, "Text primitives"),
        "models": _array(_MODEL, "Model primitives"),
    },
    "A visual element in a 3D scene",
)
_DELETION = _object(
    "foxglove.SceneEntityDeletion",
    {"timestamp": _TIME, "type": _DELETION_TYPE, "id": {"type": "string"}},
)


def frame_transforms_schema() -> dict[str, Any]:
    """`foxglove.FrameTransforms`: an array of transforms between frames."""
    return _object(
        "foxglove.FrameTransforms",
        {"transforms": _array(_FRAME_TRANSFORM, "Array of transforms")},
        "An array of FrameTransform messages",
    )


def scene_update_schema() -> dict[str, Any]:
    """`foxglove.SceneUpdate`: entities to add or replace, and deletions."""
    return _object(
        "foxglove.SceneUpdate",
        {
            "deletions": _array(_DELETION, "Scene entities to delete"),
            "entities": _array(_ENTITY, "Scene entities to add or replace"),
        },
        "An update to the entities displayed in a 3D scene",
    )
