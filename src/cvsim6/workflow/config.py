"""Loading and validating the workflow configuration (``config/*.yaml``).

The JSON schema in ``workflow/schemas/config.schema.yaml`` is the contract; this
module lets Python code and tests check a config against it without Snakemake.
Unlike Snakemake's ``validate``, defaults are *not* injected: a config is
checked as written.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import jsonschema
import yaml

__all__ = ["SCHEMA_RELPATH", "SCHEMA_PATH", "ConfigError", "find_schema", "load_config", "validate_config"]

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


def _describe(error: jsonschema.ValidationError) -> str:
    """One line per error, starting with the dotted key path."""
    where = ".".join(str(p) for p in error.absolute_path)
    if error.validator == "additionalProperties" and isinstance(error.instance, dict):
        known = set(error.schema.get("properties", {}))
        unknown = sorted(str(k) for k in error.instance if k not in known)
        keys = ", ".join(repr(k) for k in unknown)
        plural = "s" if len(unknown) > 1 else ""
        return f"unknown key{plural} {keys} in {where or 'the top level'}"
    return f"{where or '<top level>'}: {error.message}"


def validate_config(cfg: dict[str, Any], schema_path: str | Path | None = None) -> None:
    """Check ``cfg`` against the schema; raise :class:`ConfigError` naming every bad key.

    ``schema_path`` defaults to :data:`SCHEMA_PATH`. ``cfg`` is left unchanged.
    """
    path = Path(schema_path) if schema_path is not None else SCHEMA_PATH
    if path is None:
        raise FileNotFoundError(f"cannot locate {SCHEMA_RELPATH}; pass schema_path explicitly")
    with open(path, encoding="utf-8") as fh:
        schema = yaml.safe_load(fh)
    cls = jsonschema.validators.validator_for(schema, default=jsonschema.Draft202012Validator)
    cls.check_schema(schema)
    errors = sorted(cls(schema).iter_errors(cfg), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        raise ConfigError("; ".join(_describe(e) for e in errors))
