"""Loading and validating the workflow configuration (``config/*.yaml``).

The JSON schema in ``workflow/schemas/config.schema.yaml`` is the contract; this
module lets Python code and tests check a config against it without Snakemake.
Unlike Snakemake's ``validate``, defaults are *not* injected: a config is
checked as written. :func:`def_properties`, :func:`def_defaults` and
:func:`def_errors` read one ``$defs`` entry of the schema (the training
hyperparameters of one network, for :mod:`cvsim6.training.hyperparameters`).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any

import jsonschema
import yaml

__all__ = ["SCHEMA_RELPATH", "SCHEMA_PATH", "ConfigError", "def_defaults", "def_errors", "def_properties",
           "find_schema", "load_config", "load_schema", "validate_config"]

#: Location of the schema relative to the repository root.
SCHEMA_RELPATH = Path("workflow") / "schemas" / "config.schema.yaml"


class ConfigError(ValueError):
    """A configuration does not match the schema; the message names the key path."""


def find_schema(start: str | Path | None = None) -> Path | None:
    """Walk up from ``start`` (default: this file) to the first folder holding the schema."""
    here = Path(start if start is not None else __file__).resolve()
    for folder in (here, *here.parents):
        candidate = folder / SCHEMA_RELPATH
        if candidate.is_file():
            return candidate
    return None


#: The schema of the repository this package lives in (``None`` if not found,
#: e.g. for a non-editable install; pass ``schema_path`` explicitly then).
SCHEMA_PATH: Path | None = find_schema()


def load_config(path: str | Path) -> dict[str, Any]:
    """Read a YAML config file into a dict (an empty file gives ``{}``)."""
    with open(path, encoding="utf-8") as fh:
        cfg = yaml.safe_load(fh)
    if cfg is None:
        return {}
    if not isinstance(cfg, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(cfg).__name__}")
    return cfg


def _describe(error: jsonschema.ValidationError, schema: dict[str, Any]) -> str:
    """One line per error, starting with the dotted key path."""
    where = ".".join(str(p) for p in error.absolute_path)
    if error.validator in ("additionalProperties", "unevaluatedProperties") and isinstance(error.instance, dict):
        known = set(_collect_properties(error.schema, schema)[0])
        unknown = sorted(str(k) for k in error.instance if k not in known)
        keys = ", ".join(repr(k) for k in unknown)
        plural = "s" if len(unknown) > 1 else ""
        return f"unknown key{plural} {keys} in {where or 'the top level'}"
    return f"{where or '<top level>'}: {error.message}"


def load_schema(schema_path: str | Path | None = None) -> dict[str, Any]:
    """The schema at ``schema_path`` (default :data:`SCHEMA_PATH`), checked against its
    meta-schema; read once per path. Treat it as read-only."""
    path = Path(schema_path) if schema_path is not None else SCHEMA_PATH
    if path is None:
        raise FileNotFoundError(f"cannot locate {SCHEMA_RELPATH}; pass schema_path explicitly")
    return _read_schema(path.resolve())


@lru_cache(maxsize=4)
def _read_schema(path: Path) -> dict[str, Any]:
    with open(path, encoding="utf-8") as fh:
        schema = yaml.safe_load(fh)
    _validator_class(schema).check_schema(schema)
    return schema


def _validator_class(schema: dict[str, Any]) -> type:
    return jsonschema.validators.validator_for(schema, default=jsonschema.Draft202012Validator)


def validate_config(cfg: dict[str, Any], schema_path: str | Path | None = None) -> None:
    """Check ``cfg`` against the schema; raise :class:`ConfigError` naming every bad key.

    ``schema_path`` defaults to :data:`SCHEMA_PATH`. ``cfg`` is left unchanged.
    """
    schema = load_schema(schema_path)
    errors = sorted(_validator_class(schema)(schema).iter_errors(cfg), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        raise ConfigError("; ".join(_describe(e, schema) for e in errors))


def _resolve_def(ref: str, schema: dict[str, Any]) -> dict[str, Any]:
    """The ``$defs`` entry a local ``$ref`` (``"#/$defs/<name>"``) points at."""
    prefix = "#/$defs/"
    if not ref.startswith(prefix):
        raise ValueError(f"only local $defs references are followed, got {ref!r}")
    return schema["$defs"][ref[len(prefix):]]


def _collect_properties(node: dict[str, Any], schema: dict[str, Any]) -> tuple[dict[str, dict], list[str]]:
    """``({key: its subschema}, required keys)`` of the object schema ``node``: those of the
    entries it takes in through ``$ref``/``allOf`` first, then its own, in schema order."""
    props: dict[str, dict] = {}
    required: list[str] = []
    parts = ([_resolve_def(node["$ref"], schema)] if "$ref" in node else []) + list(node.get("allOf", ()))
    for sub in parts:
        sub_props, sub_required = _collect_properties(sub, schema)
        props.update(sub_props)
        required.extend(k for k in sub_required if k not in required)
    props.update(node.get("properties", {}))
    required.extend(k for k in node.get("required", ()) if k not in required)
    return props, required


def def_properties(name: str, schema_path: str | Path | None = None) -> tuple[dict[str, dict], list[str]]:
    """The keys of ``$defs/<name>``: ``({key: its subschema}, required keys)``, those of the
    entries it takes in through ``allOf``/``$ref`` first, then its own, in schema order."""
    schema = load_schema(schema_path)
    return _collect_properties(schema["$defs"][name], schema)


def def_defaults(name: str, schema_path: str | Path | None = None) -> dict[str, Any]:
    """``{key: default}`` of the keys of ``$defs/<name>`` that have a ``default``, in the order
    of :func:`def_properties`."""
    props, _ = def_properties(name, schema_path)
    return {k: sub["default"] for k, sub in props.items() if "default" in sub}


def def_errors(name: str, instance: Any, schema_path: str | Path | None = None) -> list[jsonschema.ValidationError]:
    """Every way ``instance`` breaks ``$defs/<name>`` (empty when it is valid), ordered by key."""
    schema = load_schema(schema_path)
    root = {"$schema": schema.get("$schema"), "$defs": schema["$defs"], "$ref": f"#/$defs/{name}"}
    errors = _validator_class(schema)(root).iter_errors(instance)
    return sorted(errors, key=lambda e: [str(p) for p in e.absolute_path])
