"""JSON Schemas of what pointclm writes, shipped with the package.

``result.schema.json`` (JSON Schema 2020-12) describes the JSON of ``pointclm register
--out`` and each line of ``pointclm batch --out`` / :func:`pointclm.register_files`; both
carry ``format_version`` (:data:`pointclm.batch.records.FORMAT_VERSION`). Check a file with
any JSON Schema validator, e.g.::

    import json, jsonschema
    from pointclm.schemas import result_schema
    jsonschema.validate(json.load(open("result.json")), result_schema())
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

__all__ = ["RESULT_SCHEMA", "result_schema"]

#: The file name of the result schema inside this package.
RESULT_SCHEMA = "result.schema.json"


def result_schema() -> dict[str, Any]:
    """The schema of ``register`` / ``batch`` output, as a dict (a fresh copy each call)."""
    text = resources.files(__name__).joinpath(RESULT_SCHEMA).read_text(encoding="utf-8")
    schema: dict[str, Any] = json.loads(text)
    return schema
