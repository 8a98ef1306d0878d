"""The ``ltm`` command: parse, call the library, print. User mistakes never show a traceback.

One module per command group, each with a ``register(sub)`` that adds its commands:
:mod:`~ltmstore.cli.pipeline` (demo, simulate, ingest, reconstruct, relight, evaluate, bench,
info), :mod:`~ltmstore.cli.check`, :mod:`~ltmstore.cli.share` (export, maps, view),
:mod:`~ltmstore.cli.capture` (board, calibrate, track, sync), :mod:`~ltmstore.cli.live`
(capture) and :mod:`~ltmstore.cli.archive`.
The CLI sits on top: it may import every part of the package, and ``flows`` for the Prefect-run
commands.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import warnings
from functools import partial

from ltmstore.core.errors import LtmError, LtmWarning

PREFECT_STARTUP_ENV = "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS"
PREFECT_STARTUP_TIMEOUT_S = 300  # the default of PREFECT_STARTUP_ENV when the user sets none
EPILOG = "Docs: README.md and docs/. Stores open with xarray.open_zarr(STORE, consolidated=False)."


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``ltm: error: ...``, exit 2), sub-commands too, and the
    closest option, command or choice for a misspelt one."""

    _given: list[str] = []

    def error(self, message: str):
        from ltmstore.cli.suggest import misspelt_hint, with_choice_hint

        message = with_choice_hint(message) + misspelt_hint(self, message, self._given)
        self.exit(2, f"{self.prog.split()[0]}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        # kept for error(): a required option missing may be one the user misspelt
        self._given = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None):
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:  # named by the command that does not know them, with the closest option
            from ltmstore.cli.suggest import command_parser, unrecognized

            parser = command_parser(self, parsed)
            parser.error(unrecognized(parser, extras))
        return parsed


def build_parser() -> argparse.ArgumentParser:
    """The ``ltm`` parser with every command group registered."""
    from ltmstore.cli import archive, capture, check, lights, live, pipeline, share

    parser = Parser(
        prog="ltm", description="Relightable photographs from handheld light transport "
        "acquisition: simulate, ingest, reconstruct (compressive sensing on Dask), relight.",
        epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=Parser)
    for group in (pipeline, check, share, capture, lights, live, archive):
        group.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ltm`` console script."""
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    # Prefect's temporary server (ltm demo, ltm archive run) takes 6-17 s to start, and longer
    # on a busy machine than Prefect's own 20 s default: wait for it (before Prefect is imported)
    os.environ.setdefault(PREFECT_STARTUP_ENV, str(PREFECT_STARTUP_TIMEOUT_S))
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")  # cluster chatter off
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # FFmpeg quiet: our errors say it
    os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
    from ltmstore.cli.args import join_signed_values

    logging.getLogger("asyncio").addFilter(_unretrieved)
    args = build_parser().parse_args(join_signed_values(sys.argv[1:] if argv is None else argv))
    with warnings.catch_warnings():  # the filters and the printer below, undone on return
        warnings.showwarning = partial(_one_line_warning, warnings.showwarning)
        # Zarr's warnings (a folder that is no array, ...) are store damage: `ltm check` names it
        warnings.filterwarnings("ignore", category=UserWarning, module=r"zarr(\.|$)")
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the parsed command; user mistakes and damaged stores as one line, exit 2."""
    try:
        args.func(args)
        sys.stdout.flush()  # a closed pipe (`ltm info STORE | head -1`) shows up here
    except BrokenPipeError:
        return quiet_broken_pipe()
    except LtmError as exc:
        return error_line(str(exc))
    except ValueError as exc:  # a chunk that fails its checksum, found while reading
        from ltmstore.cli.check import damaged_read

        message = damaged_read(getattr(args, "store", None), exc)
        if message is None:
            raise
        return error_line(message)
    except OSError as exc:  # the system refused: a full disk, /proc, a folder not writable
        from ltmstore.cli.oserror import os_error

        return error_line(os_error(exc, args))
    except KeyboardInterrupt:
        print("ltm: interrupted", file=sys.stderr)
        return 130
    except RuntimeError as exc:
        message = prefect_not_started(exc)
        if message is None:
            raise
        print(f"ltm: error: {one_line(message)}", file=sys.stderr)
        return 2
    return 0


def error_line(message: str) -> int:
    """Print ``message`` as the one ``ltm: error:`` line and return the exit status 2, once
    Zarr's reads and writes still in flight have ended (else the exit prints "Task was
    destroyed but it is pending" and "Event loop is closed" under it)."""
    if "zarr.core.sync" in sys.modules:  # Zarr was used: its event loop may hold tasks
        from ltmstore.core.store import settle_writes

        settle_writes(timeout=SETTLE_S)
    print(f"ltm: error: {one_line(message)}", file=sys.stderr)
    return 2


SETTLE_S = 30.0  # longest wait for Zarr's tasks in flight after an error


def prefect_not_started(exc: BaseException) -> str | None:
    """The one-line error for Prefect's temporary server that did not start (found anywhere in
    ``exc``'s chain), or None for another error."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        text = str(exc)
        if "ephemeral Prefect API server" in text:
            exited = text.partition(" Ephemeral server process ")[2].partition(".")[0]
            why = f" (its process {exited})" if exited else ""
            return (f"Prefect's temporary server did not start within "
                    f"{os.environ.get(PREFECT_STARTUP_ENV, '?')} s{why}; set {PREFECT_STARTUP_ENV} "
                    "higher, or PREFECT_API_URL to a running server (prefect server start)")
        exc = exc.__cause__ or exc.__context__
    return None


MESSAGE_MAX = 400  # characters of an error line; a longer one keeps its head and its tail


def one_line(message: str, limit: int = MESSAGE_MAX) -> str:
    """``message`` on one line (whitespace runs collapsed) of at most ``limit`` characters:
    a longer one keeps its start and its end (what was expected) around `` ... ``."""
    text = " ".join(message.split())
    if len(text) <= limit:
        return text
    tail = limit // 4
    return f"{text[:limit - tail - 5]} ... {text[-tail:]}"


def quiet_broken_pipe() -> int:
    """The reader of stdout went away: send what is left to /dev/null (so that the exit's own
    flush does not complain) and exit as a shell's pipeline expects (128 + SIGPIPE)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 128 + signal.SIGPIPE


def _unretrieved(record: logging.LogRecord) -> bool:
    """False for asyncio's "... exception was never retrieved" record: a comm future that a
    closing Dask cluster drops (a ``TimeoutError``, seen once in the suite after a full disk had
    ended the run) is printed at exit, after the command's one error line."""
    return "exception was never retrieved" not in str(record.msg)


def _one_line_warning(fallback, message, category, *args, **kwargs) -> None:
    """Print an :class:`LtmWarning` as ``ltm: warning: ...`` and a store's
    :class:`~ltmstore.core.store.NoChecksumWarning` as ``ltm: note: ...``; others as Python
    does."""
    from ltmstore.core.store import NoChecksumWarning

    if issubclass(category, NoChecksumWarning):
        print(f"ltm: note: {message}", file=sys.stderr)
    elif issubclass(category, LtmWarning):
        print(f"ltm: warning: {message}", file=sys.stderr)
    else:
        fallback(message, category, *args, **kwargs)


if __name__ == "__main__":
    sys.exit(main())
