"""No command writes an output onto its inputs or the trip store.

Every command of the app is wrapped by :func:`guard_outputs` when :func:`cevm.cli.make_app`
registers it (a new command inherits it without a line of its own): before the command
runs, its output options (:func:`is_output`: ``--out``, ``--plot``, ``--summary``, and
any option named ``out_*`` or ``*_out``) are compared with every other path option (vehicle
files, cycles, scenarios, manifests, DSMs, log paths: :func:`input_paths`) and with the
store (``--store``, or where it is by default, with its ``-wal``, ``-shm`` and
``-journal`` files) by :func:`cevm.io.outputs.output_clash`: an output that names one of
them is one line naming both, exit 2, and nothing is read or written. (``--out STORE``
once replaced a store of trips by a 10 kB CSV.) The files named only inside another
(a scenario's vehicle files) are caught where the output is opened
(:class:`cevm.io.outputs.OutFile`, against every file the command read:
:func:`cevm.io.inputs.remember_reads`, turned on here).
"""

from __future__ import annotations

import functools
from pathlib import Path, PurePath

#: Output options by name (the parameter's name in the command's function).
OUTPUT_NAMES = frozenset({"out", "plot", "summary"})

#: Options that hold paths as text (log paths and globs, a DSM that may be a GDAL URL):
#: inputs too, compared as they are named.
TEXT_PATH_NAMES = frozenset({"paths", "dsm"})

#: Marks a command function already wrapped (``make_app`` may run more than once).
_GUARDED = "__cevm_outputs_guarded__"


def is_output(name: str) -> bool:
    """Whether the parameter ``name`` is an output file's option."""
    return name in OUTPUT_NAMES or name.startswith("out_") or name.endswith("_out")


def option_names(command) -> dict[str, str]:
    """Each parameter of ``command`` as the user typed it: an option's long name
    (``--grade-file``), an argument's metavar (``SCENARIO``)."""
    import inspect
    import typing

    names = {}
    for p in inspect.signature(command, eval_str=True).parameters.values():
        shown = "--" + p.name.replace("_", "-")
        annotated = typing.get_origin(p.annotation) is typing.Annotated
        metadata = typing.get_args(p.annotation)[1:] if annotated else ()
        for info in (*metadata, p.default):
            decls = [d for d in getattr(info, "param_decls", None) or () if d.startswith("--")]
            if decls:
                shown = decls[0]
                break
            if type(info).__name__ == "ArgumentInfo":
                shown = getattr(info, "metavar", None) or p.name.upper()
                break
        names[p.name] = shown
    return names


def _paths(value, text: bool) -> list[Path]:
    """The paths in an option's value: a path, a list of them, or (``text``) strings."""
    items = value if isinstance(value, (list, tuple)) else [value]
    return [Path(v) for v in items
            if isinstance(v, PurePath) or (text and isinstance(v, str) and v and "://" not in v)]


def output_paths(kwargs: dict, names: dict[str, str]) -> list[tuple[str, Path]]:
    """(option, path) of every output option given (``names``: :func:`option_names`)."""
    return [(names.get(k, k), p) for k, v in kwargs.items() if is_output(k) for p in _paths(v, False)]


def input_paths(kwargs: dict, names: dict[str, str]) -> list[tuple[str, Path]]:
    """(option, path) of every other path option given (the store apart)."""
    return [(names.get(k, k), p) for k, v in kwargs.items() if not is_output(k) and k != "store"
            for p in _paths(v, k in TEXT_PATH_NAMES)]


def check_outputs(kwargs: dict, names: dict[str, str]) -> None:
    """Refuse (one line, exit 2) an output of the command called with ``kwargs`` that
    names an input, the store or another output (:func:`cevm.io.outputs.output_clash`)."""
    outputs = output_paths(kwargs, names)
    if not outputs:
        return
    from cevm.io.outputs import output_clash

    store = None
    if "store" in kwargs:
        from cevm.store.location import resolve_store_path

        store = resolve_store_path(kwargs["store"])
    line = output_clash(outputs, input_paths(kwargs, names), store)
    if line is not None:
        from cevm.cli.common import fail

        raise fail(line)


def guard_outputs(command):
    """``command`` (a typer command's function) checked by :func:`check_outputs` before
    it runs, with every file it reads remembered (:func:`cevm.io.inputs.remember_reads`)
    so that its outputs refuse them too; its signature (typer's options) is the
    command's (``functools.wraps``: ``inspect.signature`` follows ``__wrapped__``)."""
    if getattr(command, _GUARDED, False):
        return command

    names: dict[str, str] = {}

    @functools.wraps(command)
    def run(*args, **kwargs):
        from cevm.io.inputs import remember_reads

        if not names:
            names.update(option_names(command))
        check_outputs(kwargs, names)
        remember_reads(True)
        try:
            return command(*args, **kwargs)
        finally:
            remember_reads(False)  # the library, used after a command in the same process, keeps none

    setattr(run, _GUARDED, True)
    return run


def guard_app(app) -> None:
    """Wrap every command and group callback registered on the typer app ``app`` (and its
    groups, recursively) with :func:`guard_outputs`."""
    for info in app.registered_commands:
        if info.callback is not None:
            info.callback = guard_outputs(info.callback)
    if app.registered_callback is not None and app.registered_callback.callback is not None:
        app.registered_callback.callback = guard_outputs(app.registered_callback.callback)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            guard_app(group.typer_instance)
