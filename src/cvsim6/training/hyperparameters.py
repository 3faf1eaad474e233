"""A network's training hyperparameters (``hyper``): checked and completed from the schema.

The keys, their types, ranges, defaults and meaning live in one place, the workflow schema
(``workflow/schemas/config.schema.yaml``, ``$defs/<stage>_hyper``, read through
:mod:`cvsim6.workflow.config`). This module validates a ``hyper`` dict against that entry,
fills in its defaults, and checks in code only the rules that tie keys together, which a
JSON schema cannot state (:func:`check_cross_field_rules`).
"""
from __future__ import annotations

import math

from cvsim6.workflow.config import def_defaults, def_errors, def_properties

#: The training stages, each with a ``$defs/<stage>_hyper`` entry in the schema.
STAGES = ("emulator", "flow", "encoder_decoder")


def _schema_name(stage: str) -> str:
    if stage not in STAGES:
        raise ValueError(f"unknown training stage {stage!r}; one of {list(STAGES)}")
    return f"{stage}_hyper"


def describe(subschema: dict) -> str:
    """What a key's subschema accepts, in words: ``"a number in [0, 1]"``, ``"null or a number
    > 0"``, ``"true or false"``, ``"one of 'sum', 'mse'"``."""
    if "enum" in subschema:
        return "one of " + ", ".join(repr(v) for v in subschema["enum"])
    types = subschema.get("type", [])
    types = [types] if isinstance(types, str) else list(types)
    nullable = "null" in types
    types = [t for t in types if t != "null"]
    if types == ["boolean"]:
        words = "true or false"
    elif types in (["integer"], ["number"]):
        words = ("an integer" if types == ["integer"] else "a number") + _range_words(subschema)
    else:
        words = " or ".join(f"a {t}" for t in types) or "a value"
    return f"null or {words}" if nullable else words


def _range_words(subschema: dict) -> str:
    """`` in [lo, hi]``, `` > lo``, `` >= lo``, `` <= hi`` ... from the schema's bounds."""
    lo = ("(", subschema["exclusiveMinimum"]) if "exclusiveMinimum" in subschema else (
        ("[", subschema["minimum"]) if "minimum" in subschema else None)
    hi = (")", subschema["exclusiveMaximum"]) if "exclusiveMaximum" in subschema else (
        ("]", subschema["maximum"]) if "maximum" in subschema else None)
    if lo and hi:
        return f" in {lo[0]}{lo[1]:g}, {hi[1]:g}{hi[0]}"
    if lo:
        return f" {'>' if lo[0] == '(' else '>='} {lo[1]:g}"
    if hi:
        return f" {'<' if hi[0] == ')' else '<='} {hi[1]:g}"
    return ""


def _value_error(stage: str, key: str, subschema: dict, value) -> ValueError:
    return ValueError(f"{stage} hyperparameter {key} must be {describe(subschema)}, got {value!r}")


def check_schema(stage: str, hyper: dict) -> None:
    """Raise ``ValueError`` unless ``hyper`` matches the schema of ``stage``: missing and
    unknown keys are named together, else the first bad value with what its key accepts.
    Numbers must also be finite (JSON has no NaN or infinity)."""
    name = _schema_name(stage)
    props, required = def_properties(name)
    missing = [k for k in required if k not in hyper]
    unknown = sorted(set(hyper) - set(props))
    if missing or unknown:
        raise ValueError(f"{stage} hyperparameters: missing {missing}, unknown {unknown}")
    errors = [e for e in def_errors(name, hyper) if e.validator != "unevaluatedProperties"]  # unknown: above
    for error in sorted(errors, key=lambda e: not e.absolute_path):  # a key's value first
        if not error.absolute_path:  # not about one key's value: the schema's own words
            raise ValueError(f"{stage} hyperparameters: {error.message}")
        key = error.absolute_path[0]
        raise _value_error(stage, key, props[key], hyper[key])
    for key, value in hyper.items():
        if isinstance(value, float) and not math.isfinite(value):
            raise _value_error(stage, key, props[key], value)


def check_cross_field_rules(stage: str, h: dict) -> None:
    """The rules that tie keys of a complete ``h`` (defaults filled in) together; raise
    ``ValueError`` naming the stage, the key and its value."""
    if h["lr_schedule"] == "step" and (h["lr_step"] is None or h["lr_gamma"] is None):
        raise ValueError(f"{stage}: lr_schedule 'step' needs lr_step and lr_gamma, "
                         f"got {h['lr_step']!r}, {h['lr_gamma']!r}")
    if not h["warmup_epochs"] < h["epochs"]:
        raise ValueError(f"{stage} hyperparameter warmup_epochs must be below epochs ({h['epochs']}), "
                         f"got {h['warmup_epochs']!r}")
    if h["restarts"] > 1 and (not 1 <= h["restart_epochs"] < h["epochs"] or h["restart_epochs"] % h["eval_every"]):
        raise ValueError(f"{stage} hyperparameter restart_epochs must be an integer in [1, epochs) and a multiple of "
                         f"eval_every ({h['eval_every']}) when restarts > 1, got {h['restart_epochs']!r}")
    target, most = h.get("restart_target"), h.get("max_restarts")
    if (target is not None and h["restarts"] == 1) or (most is not None and (target is None or most < h["restarts"])):
        raise ValueError(f"encoder_decoder hyperparameters restart_target and max_restarts need restarts > 1, a "
                         f"restart_target, and max_restarts >= restarts ({h['restarts']}), got restart_target "
                         f"{h['restart_target']!r}, max_restarts {h['max_restarts']!r}")
    if stage == "encoder_decoder" and h["kl_warmup_epochs"] > h["epochs"]:
        raise ValueError(f"encoder_decoder hyperparameter kl_warmup_epochs must be at most epochs ({h['epochs']}), "
                         f"got {h['kl_warmup_epochs']!r}")


def check_hyper(stage: str, hyper: dict) -> dict:
    """Validated copy of ``hyper`` for ``stage`` (``"emulator"``, ``"flow"``,
    ``"encoder_decoder"``) with the schema's defaults filled in: the defaults' keys first, in
    schema order, then the other keys in ``hyper``'s order."""
    check_schema(stage, hyper)
    h = {**def_defaults(_schema_name(stage)), **hyper}
    check_cross_field_rules(stage, h)
    return h
