"""Before any rule: the config validated, the stale locks cleared, the package's bytecode
written and Snakemake's wake-up timers bounded (``prepare``); a bad value said in one line
(``refusals``)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from cape.bytecode import precompile_package
from cape.errors import CapeError, one_line
from cape.storage.locks import clear_stale_locks
from cape.workflow.scheduler import bound_wakeup_timers

SOURCE = "config (config/config.yaml and any --configfile)"


def prepare(config: dict[str, Any], main_process: bool) -> None:
    """Before any rule: in the main process, remove the locks of runs proven ended
    (cape/storage/locks.py) and write the package's bytecode once (cape/bytecode.py); everywhere,
    validate the config (``validate``) and bound the scheduler's wake-up timers
    (cape/workflow/scheduler.py)."""
    bound_wakeup_timers()
    if main_process:
        clear_stale_locks(".", report=lambda message: print(message, file=sys.stderr))
        precompile_package()
    validate(config, SOURCE)


def validate(config: dict[str, Any], source: str) -> None:
    """The config against its schema and cross-field rules (cape.config, which fills in the
    schema's defaults), each controller's and disturbance source's own keys, and each model's
    module imported (it registers the model); each problem one ``CapeError`` naming the key and
    the fix."""
    from cape.closedloop.disturbances import validate_sources
    from cape.config import validate_config
    from cape.controllers import controller_class
    from cape.controllers.base import validate_settings
    from cape.models.registry import model_class
    from cape.specs.run import DisturbancesSpec
    from cape.specs.study import StudySpec

    validate_config(config, source)
    study = StudySpec.from_config(config)
    for name, entry in study.controllers.items():
        validate_settings(controller_class(name, entry), name, entry, source)
    validate_sources(DisturbancesSpec.from_config(config).sources, source)
    for name, entry in study.models.items():
        model_class(name, entry)


@contextmanager
def refusals() -> Iterator[None]:
    """A ``CapeError`` raised while Snakemake reads the workflow (a bad config value, a grid it
    cannot build) as its one-line reason on stderr and exit status 1. Snakemake would print
    any exception, ``WorkflowError`` included, with the ``File "…"`` lines of its traceback,
    which tell a user who gave a bad value nothing; a ``SystemExit`` it lets through."""
    try:
        yield
    except CapeError as error:
        print(f"error: {one_line(str(error))}", file=sys.stderr)  # as `cape` says it
        raise SystemExit(1) from None


class Refusing:
    """``target``'s methods, each called inside ``refusals``: what a rule's params call while
    Snakemake plans (the job files), whose ``CapeError`` Snakemake would wrap in an
    InputFunctionException with its stack frames; a ``SystemExit`` it lets through and stops
    (it plans before it locks the folder or starts a job)."""

    def __init__(self, target: object) -> None:
        self._target = target

    def __getattr__(self, name: str) -> Any:
        method = getattr(self._target, name)
        if not callable(method):
            return method

        def refusing(*args: Any, **kwargs: Any) -> Any:
            with refusals():
                return method(*args, **kwargs)

        return refusing
