"""Generic adapter between a Snakemake rule and one function of the cvsim6 package.

Every rule uses ``script: "../scripts/call.py"`` and names the function in
``params: function="module:function"``. The function is called with keyword
arguments:

* every *named* input except ``code`` (the package sources, declared only to
  trigger reruns),
* every *named* output,
* every named param except ``function``,
* ``threads=snakemake.threads`` if the function accepts ``threads``
  (or ``**kwargs``).

A single path is passed as ``str``, several paths as ``list[str]``. Logging
(INFO, with timestamps) and everything written to stdout/stderr, including
tqdm progress bars and messages from compiled code, go to ``log[0]``. An
exception is logged with its traceback and re-raised, so the job fails; a
:class:`cvsim6.errors.UserFacingError` (a setting to change, e.g. a failed
download) is logged as one line, without a traceback, and the job exits 1.
"""
import importlib
import inspect
import logging
import os
import sys

from cvsim6.errors import UserFacingError

# ``snakemake`` is injected by Snakemake's script directive.
smk = snakemake  # noqa: F821


def _paths(value):
    """A path as ``str``; a list of paths as ``list[str]``."""
    if isinstance(value, str):
        return str(value)
    return [str(v) for v in value]


def _kwargs(function):
    """Keyword arguments for ``function`` from the rule's named inputs, outputs and params."""
    kwargs = {}
    for name, value in smk.input.items():
        if name != "code":
            kwargs[name] = _paths(value)
    for name, value in smk.output.items():
        kwargs[name] = _paths(value)
    for name, value in smk.params.items():
        if name != "function":
            kwargs[name] = value
    parameters = inspect.signature(function).parameters
    if "threads" in parameters or any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
        kwargs["threads"] = smk.threads
    return kwargs


def _redirect_to_log():
    """Send logging, stdout and stderr (Python and file-descriptor level) to log[0]."""
    if not smk.log:
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
        return
    os.makedirs(os.path.dirname(smk.log[0]) or ".", exist_ok=True)
    log = open(smk.log[0], "w", buffering=1, encoding="utf-8")
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)
    sys.stdout = sys.stderr = log
    logging.basicConfig(
        level=logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=log,
        force=True,
    )


def main():
    _redirect_to_log()
    logger = logging.getLogger("call")
    target = smk.params.function
    try:
        module_name, function_name = target.split(":")
        function = getattr(importlib.import_module(module_name), function_name)
        kwargs = _kwargs(function)
        logger.info("rule %s: %s(%s)", smk.rule, target, ", ".join(f"{k}={v!r}" for k, v in kwargs.items()))
        function(**kwargs)
        logger.info("rule %s: done", smk.rule)
    except UserFacingError as e:  # a setting or input to change: its message says which
        logger.error("rule %s: %s", smk.rule, e)
        sys.exit(1)
    except Exception:
        logger.exception("rule %s: %s failed", smk.rule, target)
        raise


main()
